"""Operator requests signed with Ed25519 (issue 43): what an operator signs when asking a node to change what a
robot does (load a policy file, accept older weights), and what the node checks before it obeys. ROS-free: the
node's adapter (``ros/operator_gate.py``) hands in the request's fields as a mapping.

Why: DDS without SROS2 does not say who sent a request, so any process on the domain could call a node's services.
A signature by a key the node trusts (``trusted_operator_keys``) proves an operator made *this* request: it covers

- every field of the request but the signature (by name, typed, sorted),
- the target node's fully qualified name and the service's name (a request signed for one robot's node, or for
  another service, does not verify on another),
- the signing time (refused when more than ``window_s``, 30 s, from the node's clock: ``stale``) and a 16-byte
  random nonce the node accepts once (``replayed``; nonces are kept for the window, after which the time refuses a
  replay anyway).

Canonical bytes (``canonical_bytes``): a domain tag, then node, service, key id, stamp (int64 s, uint32 ns), nonce,
the field count and each field as name, type tag and value — every part a 4-byte big-endian length and its bytes,
so no two different requests share them. Reasons, in the order checked: ``unsigned``, ``malformed``,
``untrusted_key``, ``bad_signature``, ``stale``, ``replayed``.

Policy files loaded at run time carry a detached signature beside them (``FILE.sig``, one JSON line: key id,
SHA-256, signature over a domain tag and the SHA-256; ``sign_file``, ``verify_file``): reasons ``file_unsigned``,
``file_untrusted_key``, ``file_bad_signature``.
"""
from __future__ import annotations

import hashlib
import json
import math
import os
import re
import secrets
import struct
from collections import OrderedDict
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

from cryptography.exceptions import InvalidSignature
from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey, Ed25519PublicKey

from dynenv_ros.security.keys import key_id as key_id_of
from dynenv_ros.security.weights_signing import Refused

DOMAIN = b"dynenv/OperatorRequest/1"
FILE_DOMAIN = b"dynenv/PolicyFile/1"
NONCE_BYTES = 16
SIGNATURE_BYTES = 64
WINDOW_S = 30.0                  # freshness: a request signed further than this from the node's clock is stale
MAX_NONCES = 65_536              # replay guard's bound (only verified requests enter it: an operator's own rate)
MAX_SIG_FILE_BYTES = 4096        # a .sig file is one JSON line of about 250 bytes
SIG_SUFFIX = ".sig"
# Every reason a request is refused for (diagnostics keys operator_refused_<reason>), and a file's.
REASONS = ("unsigned", "malformed", "untrusted_key", "bad_signature", "stale", "replayed")
FILE_REASONS = ("file_unsigned", "file_untrusted_key", "file_bad_signature")
_KEY_ID = re.compile(r"[0-9a-f]{16}")
_SHA256 = re.compile(r"[0-9a-f]{64}")
FieldValue = str | bool | int | float | bytes


@dataclass(frozen=True)
class Signature:
    """An ``OperatorSignature`` without ROS: who signed, when (wall clock), the nonce and the signature."""
    key_id: str = ""
    stamp_sec: int = 0
    stamp_nanosec: int = 0
    nonce: bytes = b""
    signature: bytes = b""

    @property
    def stamp_ns(self) -> int:
        return self.stamp_sec * 1_000_000_000 + self.stamp_nanosec

    @property
    def empty(self) -> bool:
        return not (self.key_id or self.nonce or self.signature or self.stamp_sec or self.stamp_nanosec)


def _part(data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + data


def _value(value: FieldValue) -> bytes:
    """A typed field value: a type tag and its bytes (a string "1" and an integer 1 differ)."""
    if isinstance(value, bool):                    # before int: bool is an int in Python
        return b"b" + (b"\x01" if value else b"\x00")
    if isinstance(value, int):
        return b"i" + str(value).encode()
    if isinstance(value, float):
        if not math.isfinite(value):
            raise ValueError(f"a request field is {value}: only finite numbers are signed")
        return b"f" + struct.pack(">d", value)
    if isinstance(value, str):
        return b"s" + value.encode()
    if isinstance(value, (bytes, bytearray, memoryview)):
        return b"x" + bytes(value)
    raise ValueError(f"a request field of type {type(value).__name__} cannot be signed (str, bool, int, float, "
                     "bytes)")


def canonical_bytes(node: str, service: str, fields: Mapping[str, FieldValue], signature: Signature) -> bytes:
    """What is signed (module docstring): the signature's own ``signature`` bytes excluded."""
    s = signature
    parts = [DOMAIN, node.encode(), service.encode(), s.key_id.encode(), struct.pack(">qI", s.stamp_sec,
                                                                                        s.stamp_nanosec),
             bytes(s.nonce), struct.pack(">I", len(fields))]
    for name in sorted(fields):
        parts += [name.encode(), _value(fields[name])]
    return b"".join(_part(p) for p in parts)


def sign_request(private_key: Ed25519PrivateKey, node: str, service: str, fields: Mapping[str, FieldValue],
                 now_ns: int, nonce: bytes | None = None) -> Signature:
    """The signature an operator attaches to a request for ``service`` of node ``node`` (fully qualified, e.g.
    ``/policy_node``) at wall-clock ``now_ns``; a fresh random nonce unless one is given (tests)."""
    if not node.startswith("/"):
        raise ValueError(f"node {node!r} must be the fully qualified name (e.g. /policy_node)")
    nonce = secrets.token_bytes(NONCE_BYTES) if nonce is None else nonce
    sec, nanosec = divmod(now_ns, 1_000_000_000)
    unsigned = Signature(key_id_of(private_key.public_key()), sec, nanosec, nonce, b"")
    data = private_key.sign(canonical_bytes(node, service, fields, unsigned))
    return Signature(unsigned.key_id, sec, nanosec, nonce, data)


class RequestVerifier:
    """A node's side: its trusted operator keys, its fully qualified name, the freshness window and the replay
    guard (the nonces of requests accepted within the window)."""

    def __init__(self, trusted: Mapping[str, Ed25519PublicKey], node: str, window_s: float = WINDOW_S,
                 max_nonces: int = MAX_NONCES) -> None:
        if not window_s > 0 or max_nonces < 1:
            raise ValueError(f"window_s {window_s} and max_nonces {max_nonces} must be positive")
        self.trusted, self.node = dict(trusted), node
        self.window_ns = round(window_s * 1e9)
        self.max_nonces = max_nonces
        self._seen: OrderedDict[bytes, int] = OrderedDict()     # nonce -> stamp (ns), oldest first

    def check(self, service: str, fields: Mapping[str, FieldValue], signature: Signature, now_ns: int) -> None:
        """Return if an operator signed exactly this request for this node within the window and it was not seen
        before (its nonce is then remembered); else Refused with the reason (module docstring)."""
        s = signature
        if s.empty:
            raise Refused("unsigned", f"{service} needs an operator's signature (dynenv-keys call)")
        if not _KEY_ID.fullmatch(s.key_id) or len(s.nonce) != NONCE_BYTES or len(s.signature) != SIGNATURE_BYTES \
                or s.stamp_sec < 0 or not 0 <= s.stamp_nanosec < 1_000_000_000:
            raise Refused("malformed", f"signature fields malformed: key id {s.key_id[:16]!r}, nonce of "
                                       f"{len(s.nonce)} bytes (want {NONCE_BYTES}), signature of {len(s.signature)} "
                                       f"(want {SIGNATURE_BYTES}), stamp {s.stamp_sec} s {s.stamp_nanosec} ns (want "
                                       "sec >= 0, nanosec < 10^9)")
        key = self.trusted.get(s.key_id)
        if key is None:
            raise Refused("untrusted_key", f"signed by key {s.key_id}, which this node does not trust")
        try:
            key.verify(bytes(s.signature), canonical_bytes(self.node, service, fields, s))
        except (InvalidSignature, ValueError):
            raise Refused("bad_signature", f"the signature of key {s.key_id} does not match this request to "
                                           f"{self.node}/{service} (altered, or signed for another node or "
                                           "service)") from None
        skew = s.stamp_ns - now_ns
        if abs(skew) > self.window_ns:
            raise Refused("stale", f"signed {abs(skew) / 1e9:.1f} s {'ahead of' if skew > 0 else 'before'} this "
                                   f"node's clock (window {self.window_ns / 1e9:.0f} s)")
        self._forget(now_ns)
        nonce = bytes(s.nonce)
        if nonce in self._seen:
            raise Refused("replayed", f"nonce {nonce.hex()[:12]}… was accepted before")
        self._seen[nonce] = s.stamp_ns
        while len(self._seen) > self.max_nonces:
            self._seen.popitem(last=False)

    def _forget(self, now_ns: int) -> None:
        """Drop nonces whose stamp left the window: the freshness check alone refuses them now."""
        for nonce, stamp in list(self._seen.items()):
            if abs(stamp - now_ns) > self.window_ns:
                del self._seen[nonce]


# -- detached signatures of policy files ------------------------------------------------------------------------
def signature_path(path: str | os.PathLike[str]) -> Path:
    """Where a file's detached signature lies: ``FILE.sig``."""
    return Path(str(path) + SIG_SUFFIX)


def _file_message(sha256: str, key_id: str) -> bytes:
    return _part(FILE_DOMAIN) + _part(sha256.encode()) + _part(key_id.encode())


def sign_file(private_key: Ed25519PrivateKey, path: str | os.PathLike[str]) -> Path:
    """Write ``FILE.sig`` (replacing an older one: it signs the bytes of now) and return its path."""
    file = Path(path).expanduser()
    digest = hashlib.sha256(file.read_bytes()).hexdigest()
    kid = key_id_of(private_key.public_key())
    signed = {"key_id": kid, "sha256": digest, "signature": private_key.sign(_file_message(digest, kid)).hex()}
    target = signature_path(file)
    target.write_text(json.dumps(signed) + "\n")
    return target


def verify_file(data: bytes, signature_file: str | os.PathLike[str],
                trusted: Mapping[str, Ed25519PublicKey]) -> str:
    """The signer's key id if ``signature_file`` is a trusted key's signature of exactly ``data`` (the bytes the
    node read once and will load: no second read between check and load); else Refused (``FILE_REASONS``)."""
    sig_path = Path(signature_file)
    try:
        if sig_path.stat().st_size > MAX_SIG_FILE_BYTES:
            raise Refused("file_bad_signature", f"{sig_path} is larger than a signature ({MAX_SIG_FILE_BYTES} "
                                                "bytes at most)")
        fields = json.loads(sig_path.read_text())
    except FileNotFoundError:
        raise Refused("file_unsigned", f"no detached signature {sig_path.name} beside the file (sign it with "
                                       "dynenv-keys sign-file)") from None
    except (OSError, ValueError) as error:
        raise Refused("file_bad_signature", f"{sig_path} cannot be read: {error}") from None
    if not isinstance(fields, dict) or not isinstance(fields.get("key_id"), str) or \
            not isinstance(fields.get("sha256"), str) or not isinstance(fields.get("signature"), str):
        raise Refused("file_bad_signature", f"{sig_path} is not a detached signature (key_id, sha256, signature)")
    kid, digest = fields["key_id"], fields["sha256"]
    if not _KEY_ID.fullmatch(kid) or kid not in trusted:
        raise Refused("file_untrusted_key", f"{sig_path.name} is signed by key {kid[:16]!r}, which this node does "
                                            "not trust")
    actual = hashlib.sha256(data).hexdigest()
    if not _SHA256.fullmatch(digest) or digest != actual:
        raise Refused("file_bad_signature", f"{sig_path.name} signs sha256 {digest[:12]}, the file's is "
                                            f"{actual[:12]} (changed since it was signed)")
    try:
        trusted[kid].verify(bytes.fromhex(fields["signature"]), _file_message(digest, kid))
    except (InvalidSignature, ValueError):
        raise Refused("file_bad_signature", f"{sig_path.name}: the signature does not match key {kid}") from None
    return kid
