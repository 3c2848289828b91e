"""Connecting this process to Ray — an embedded local Ray, or a running cluster at ``HOST:PORT`` — with a bounded
wait and a one-line reason when it cannot, for the asynchronous runner's Ray workers (``ray_pool``) and the grid
command (``sweep``). Ray is imported only here and in those two modules; nothing else in the project needs it.

Why the care:

- Ray waits up to about 12 minutes for an address nobody answers at, and its own timeouts are read from the
  environment once, when ``ray`` is first imported. So the address is first probed with a plain TCP connect
  (refused, unreachable or silent: a one-line error within ``timeout``), Ray's timeouts are set before the import,
  and ``ray.init`` of a cluster runs in a daemon thread the caller stops waiting for after ``timeout``. (An embedded
  Ray starts in the calling thread: Ray ties the processes it starts to the life of the thread that started them.)
- Ray's processes listen on every interface. An embedded Ray gets a random per-run token (``RAY_AUTH_MODE=token``,
  ``RAY_AUTH_TOKEN``) unless the user set one, so nothing else on the network can submit work to it, and nothing is
  written to ``~/.ray``. A cluster is joined with whatever ``RAY_AUTH_MODE`` / ``RAY_AUTH_TOKEN`` the user's
  environment holds (docs/training.md, "On a Ray cluster").
- Ray replaces 127.0.0.1 and localhost by the machine's first routable address; a loopback cluster on one machine
  (the tests) uses other 127/8 addresses, which it keeps.
"""
from __future__ import annotations

import os
import secrets
import socket
import sys
import threading
from typing import Any

# Ray's own waits for a cluster that does not answer (seconds), read when ``ray`` is imported
_CONNECT_TIMEOUTS = ("RAY_gcs_server_port_wait_time_s", "RAY_py_gcs_connect_timeout_s",
                     "RAY_gcs_rpc_server_connect_timeout_s")


class RayConnectionError(RuntimeError):
    """Ray could not be started or joined; the message is one line saying why."""


def parse_address(address: str) -> tuple[str, int]:
    host, _, port = address.rpartition(":")
    if not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise RayConnectionError(f"ray_address {address!r}: expected HOST:PORT")
    return host.strip("[]"), int(port)


def probe(address: str, timeout: float) -> str:
    """The local address this machine reaches the cluster's head from, once a TCP connection to it opened within
    ``timeout`` seconds (RayConnectionError if none did)."""
    host, port = parse_address(address)
    try:
        with socket.create_connection((host, port), timeout=timeout) as connection:
            local = connection.getsockname()[0]
    except OSError as error:
        reason = "timed out" if isinstance(error, socket.timeout) else (error.strerror or str(error))
        raise RayConnectionError(f"ray_address {address}: no Ray head answers there within {timeout:g} s "
                                 f"({reason})") from None
    # a head on loopback is this machine's own node (Ray would take 127.0.0.1 for the first routable address)
    return host if host.startswith("127.") else local


def _prepare_environment(timeout: float, embedded: bool) -> None:
    seconds = str(max(1, int(timeout / 4)))
    for name in _CONNECT_TIMEOUTS:
        os.environ.setdefault(name, seconds)
    os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")
    if embedded and "RAY_AUTH_MODE" not in os.environ:
        os.environ["RAY_AUTH_MODE"] = "token"
        os.environ.setdefault("RAY_AUTH_TOKEN", secrets.token_hex(32))


def connect(address: str | None, timeout: float, num_cpus: int | None = None,
            object_store_mb: int = 256) -> tuple[Any, bool]:
    """(the ``ray`` module, whether this call started Ray): an embedded local Ray with ``num_cpus`` CPUs when
    ``address`` is None, else the cluster at ``address``. Reuses a Ray this process already joined."""
    node_ip = probe(address, timeout) if address is not None else None
    if "ray" not in sys.modules:
        _prepare_environment(timeout, embedded=address is None)
    try:
        import ray
    except ImportError:
        raise RayConnectionError("backend 'ray' needs the ray package (pip install 'ray==2.60.0'; "
                                 "requirements.lock has it)") from None
    if ray.is_initialized():
        return ray, False
    outcome: dict[str, Any] = {}

    def start() -> None:
        try:
            if address is None:
                ray.init(num_cpus=num_cpus, include_dashboard=False, object_store_memory=object_store_mb << 20,
                         log_to_driver=False, logging_level="ERROR", configure_logging=True)
            else:
                # this machine is one of the cluster's nodes, known by the address it reaches the head from
                ray.init(address=address, _node_ip_address=node_ip, log_to_driver=False, logging_level="ERROR")
        except BaseException as error:       # reported to the caller below
            outcome["error"] = error

    where = "an embedded local Ray" if address is None else f"the Ray cluster at {address}"
    if address is None:
        # here, not in a thread: Ray ties the processes it starts to the starting thread's life (PR_SET_PDEATHSIG)
        start()
    else:
        thread = threading.Thread(target=start, name="ray-connect", daemon=True)
        thread.start()
        thread.join(timeout)
        if thread.is_alive():
            raise RayConnectionError(f"could not join {where} within {timeout:g} s")
    if "error" in outcome:
        error = outcome["error"]
        text = " ".join(str(error).split())[:300]
        raise RayConnectionError(f"could not start or join {where}: {type(error).__name__}: {text}")
    return ray, True


def cluster_cpus(ray: Any) -> int:
    return int(ray.cluster_resources().get("CPU", 0))
