"""The policy node's operator services (issue 43; docs/ros_graph.md, "Who may command a node"): ``~/load_policy``
and ``~/accept_older_weights`` change what the robot does, so they exist only when the node is given
``trusted_operator_keys``, and obey only a request an operator signed for this node (``ros.operator_gate``);
anything else is refused with the reason, counted in ``~/diagnostics``. A file LoadPolicy names must carry a trusted
detached signature (``FILE.sig``) unless the node was started with ``allow_unsigned_files``; the bytes checked are
the bytes loaded (read once). A mixin of ``PolicyNode``: it reads the node's state and swaps through ``_swap``.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any

from dynenv_msgs.srv import LoadPolicy
from rclpy.exceptions import ParameterException

from dynenv_ros.agent.checkpoint import MAX_POLICY_BYTES, check_file_size
from dynenv_ros.ros.operator_gate import OperatorGate
from dynenv_ros.security.keys import KeyFileError, load_trusted_keys
from dynenv_ros.security.operator_requests import signature_path, verify_file
from dynenv_ros.security.weights_signing import Refused
from policy_node.batch_policy import one_line as _one_line
from policy_node.policy_files import runtime_of


class OperatorServices:
    """``_operator_gate`` at start, ``_on_load`` serving ``~/load_policy`` (module docstring)."""

    operator: OperatorGate | None
    allow_unsigned_files: bool
    counts: Any
    batch: Any

    def _operator_gate(self, key_paths: list[str]) -> OperatorGate | None:
        """The gate of the operator services, or None (they are off) without trusted operator keys: said once."""
        try:
            trusted = load_trusted_keys(key_paths)
        except KeyFileError as error:
            raise ParameterException(str(error), ["trusted_operator_keys"]) from None
        if not trusted:
            self.get_logger().info("no trusted_operator_keys: ~/load_policy and ~/accept_older_weights are off "
                                   "(give the operators' public keys to turn them on, e.g. -p "
                                   "trusted_operator_keys:=[~/.config/dynenv_ros/keys/operator.pub])")
            return None
        self.get_logger().info(f"~/load_policy and ~/accept_older_weights obey requests signed by "
                               f"{', '.join(sorted(trusted))}; files "
                               f"{'need no signature (allow_unsigned_files)' if self.allow_unsigned_files else 'need a trusted FILE.sig'}")
        return OperatorGate(self, trusted, self.counts)

    def _on_load(self, request: LoadPolicy.Request, response: LoadPolicy.Response):
        """Only an operator's signed request, and (unless ``allow_unsigned_files``) a file with a trusted
        detached signature; the bytes verified are the bytes loaded."""
        refused, data = self.operator.refusal("load_policy", request), None
        if refused is None and not self.allow_unsigned_files:
            refused, data = self._signed_file(request.checkpoint_path)
        if refused is not None:
            response.success, response.reason = False, refused[0]
            response.message = f"kept the current policy: refused ({refused[0]}): {refused[1]}"
            return response
        runtime = request.runtime or runtime_of(request.checkpoint_path)
        try:
            policy, digest, version = self._load(request.checkpoint_path, runtime, data)
        except ValueError as error:
            response.success, response.reason = False, "load_failed"
            response.message = f"kept the current policy: {error}"
            self.get_logger().warning(f"LoadPolicy {request.checkpoint_path!r}: {response.message}")
            return response
        self._swap(policy, digest, version)
        self.runtime_name, self.weights_acting = runtime, None
        response.success, response.checkpoint_sha256 = True, digest
        response.message = f"loaded ({runtime}); its trial decision on {self.batch.trial_note} passed"
        self.get_logger().info(f"loaded {request.checkpoint_path} ({runtime}, sha256 {digest[:12]})")
        return response

    def _signed_file(self, path: str) -> tuple[tuple[str, str] | None, bytes | None]:
        """(None, the file's bytes) when they carry a trusted operator's detached signature — read once, bounded,
        and loaded from memory, so the file cannot change between check and load; else ((reason, text), None), a
        signature problem counted as an operator refusal."""
        try:
            file = Path(path)
            check_file_size(file, "policy file")
            with file.open("rb") as handle:
                data = handle.read(MAX_POLICY_BYTES + 1)
            verify_file(data, signature_path(file), self.operator.verifier.trusted)
        except Refused as refused:
            return self.operator.refuse("load_policy", refused.reason, f"{path}: {refused}"), None
        except (OSError, ValueError) as error:
            self.get_logger().warning(f"LoadPolicy {path!r}: {_one_line(error)}")
            return ("load_failed", _one_line(error)), None
        return None, data
