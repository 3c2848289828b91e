"""The ROS side of signed operator requests (issue 43; the checks are ``security/operator_requests.py``): turn a
service request into the mapping of fields that was signed, its ``OperatorSignature`` into a ``Signature``, and
let a node refuse, count and log an unsigned or forged request in one call (``OperatorGate.refusal``).

The same field extraction signs (``dynenv-keys call``, ``sign_message``) and verifies, so what the operator signs
is exactly what the node checks: every request field but ``signature``, as the message holds it (a uint8 sequence
as bytes). Nested messages other than the signature are refused: no service here has one.
"""
from __future__ import annotations

import time
from collections import Counter
from collections.abc import Mapping
from typing import Any

from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey, Ed25519PublicKey

from dynenv_ros.security.operator_requests import (FILE_REASONS, REASONS, WINDOW_S, FieldValue, RequestVerifier,
                                                   Signature, sign_request)
from dynenv_ros.security.weights_signing import Refused

SIGNATURE_FIELD = "signature"


def request_fields(request: Any) -> dict[str, FieldValue]:
    """Every field of a service request but its signature, typed as signed."""
    fields: dict[str, FieldValue] = {}
    for name, kind in request.get_fields_and_field_types().items():
        if name == SIGNATURE_FIELD:
            continue
        value = getattr(request, name)
        if kind.startswith(("sequence<uint8", "uint8[")) or isinstance(value, (bytes, bytearray)):
            value = bytes(value)
        elif hasattr(value, "get_fields_and_field_types") or isinstance(value, (list, tuple)):
            raise ValueError(f"request field {name} ({kind}) cannot be signed: only plain fields are")
        fields[name] = value
    return fields


def signature_from_message(msg: Any) -> Signature:
    """``dynenv_msgs/OperatorSignature`` -> ``Signature``."""
    return Signature(key_id=msg.key_id, stamp_sec=int(msg.stamp.sec), stamp_nanosec=int(msg.stamp.nanosec),
                     nonce=bytes(msg.nonce), signature=bytes(msg.signature))


def fill_signature(msg: Any, signature: Signature) -> Any:
    """Write ``signature`` into a ``dynenv_msgs/OperatorSignature``."""
    msg.key_id = signature.key_id
    msg.stamp.sec, msg.stamp.nanosec = signature.stamp_sec, signature.stamp_nanosec
    msg.nonce = list(signature.nonce)
    msg.signature = list(signature.signature)
    return msg


def sign_message(request: Any, private_key: Ed25519PrivateKey, node: str, service: str,
                 now_ns: int | None = None) -> Any:
    """Sign a request in place for ``service`` (its name relative to the node, e.g. ``load_policy``) of ``node``
    (fully qualified), at wall-clock ``now_ns`` (default: now); returns it."""
    stamp = time.time_ns() if now_ns is None else now_ns
    signature = sign_request(private_key, node, service, request_fields(request), stamp)
    fill_signature(getattr(request, SIGNATURE_FIELD), signature)
    return request


class OperatorGate:
    """A node's gate for its operator services: verifies each request (``RequestVerifier``, wall clock), counts
    operator_requests_accepted, operator_refused and operator_refused_<reason>, keeps the last refusal and logs
    refusals (throttled: a flood of unsigned calls is counted, not a line each)."""

    def __init__(self, node: Any, trusted: Mapping[str, Ed25519PublicKey], counts: Counter,
                 window_s: float = WINDOW_S) -> None:
        self.node, self.counts = node, counts
        self.verifier = RequestVerifier(trusted, node.get_fully_qualified_name(), window_s)
        self.last_refusal = ""

    def refusal(self, service: str, request: Any) -> tuple[str, str] | None:
        """None if an operator signed ``request`` for this node's ``service`` (relative name), else (reason, text)."""
        try:
            fields = request_fields(request)
            self.verifier.check(service, fields, signature_from_message(getattr(request, SIGNATURE_FIELD)),
                                time.time_ns())
        except Refused as refused:
            return self.refuse(service, refused.reason, str(refused))
        except ValueError as error:
            return self.refuse(service, "malformed", str(error))
        self.counts["operator_requests_accepted"] += 1
        return None

    def refuse(self, service: str, reason: str, text: str) -> tuple[str, str]:
        """Count and log a refusal of ``service`` (a request's or, for load_policy, its file's)."""
        self.counts["operator_refused"] += 1
        self.counts[f"operator_refused_{reason}"] += 1
        self.last_refusal = f"{service}: {reason}: {text}"
        self.node.get_logger().warning(f"~/{service} refused: {reason}: {text}", throttle_duration_sec=5.0)
        return reason, text

    def diagnostics(self) -> dict[str, str]:
        values = {"operator_trusted_keys": str(len(self.verifier.trusted)),
                  "operator_requests_accepted": str(self.counts.get("operator_requests_accepted", 0)),
                  "operator_refused": str(self.counts.get("operator_refused", 0)),
                  "operator_refusal": self.last_refusal}
        for reason in (*REASONS, *FILE_REASONS):
            values[f"operator_refused_{reason}"] = str(self.counts.get(f"operator_refused_{reason}", 0))
        return values
