"""Signed operator requests in tests (issue 43): one operator key pair per test process, and a signed service call
that re-signs each time it re-sends (a re-sent request with the same nonce would be refused as replayed)."""
from __future__ import annotations

import functools
import tempfile
from pathlib import Path
from typing import Any

from dynenv_ros.ros.operator_gate import sign_message
from dynenv_ros.security.keys import generate_key_pair, load_private_key
from ros_harness import spin_until


@functools.lru_cache(maxsize=None)
def operator_pair() -> tuple[Path, Path]:
    """(operator.key, operator.pub) made once per process in a private temporary folder."""
    return generate_key_pair(tempfile.mkdtemp(prefix="dynenv_operator_"), "operator")


def operator_params(allow_unsigned_files: bool = True) -> dict[str, Any]:
    """A policy node's parameters trusting the test operator (files unsigned allowed unless said otherwise)."""
    return {"trusted_operator_keys": [str(operator_pair()[1])], "allow_unsigned_files": allow_unsigned_files}


def signed_call(node: Any, executor: Any, kind: Any, service: str, request: Any, key: Path | None = None,
                target: str | None = None, timeout_s: float = 20.0, resend_after_s: float = 2.0) -> Any:
    """Call ``service`` (e.g. ``/policy_node/load_policy``) with ``request`` signed by ``key`` (default: the test
    operator's) for node ``target`` (default: the service's node); re-sent, freshly signed, while no answer came.
    Returns the response, or None."""
    import time
    private = load_private_key(key or operator_pair()[0])
    node_name, _, short = service.rpartition("/")
    client = node.create_client(kind, service)
    assert client.wait_for_service(timeout_sec=min(timeout_s, 10.0)), service
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        future = client.call_async(sign_message(request, private, target or node_name, short))
        if spin_until(executor, future.done, min(resend_after_s, max(0.0, deadline - time.monotonic()))):
            return future.result()
        client.remove_pending_request(future)
    return None
