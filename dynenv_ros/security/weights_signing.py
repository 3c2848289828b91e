"""Signed weights announcements: the one canonical encoding a trainer signs and a policy node verifies, and the
checks of an announcement's own fields (before any byte of the weights travels).

An announcement (``dynenv_msgs/WeightsAnnouncement``, mirrored here without ROS as ``Announcement``) promises a
policy file: its run, version, size, SHA-256 and network shape. The trainer signs it with Ed25519; a policy node
fetches the file only if a key it trusts signed exactly these fields, and loads it only if the bytes hash to the
signed SHA-256. So whoever may publish on the ROS graph can still announce, but only a holder of a trusted private
key can make a node change its weights.

Canonical bytes (``canonical_bytes``): a domain tag, then every field but the signature in message order, each as
a 4-byte big-endian length and its bytes; integers fixed-width big-endian (stamp seconds int32 and nanoseconds
uint32 as one 8-byte field, version uint32, size uint64), strings UTF-8. Length prefixes make the encoding
injective: no two different announcements share their canonical bytes (moving a character from ``run_id`` into
``frame_id`` changes a length), so a signature cannot be carried over to another announcement.
"""
from __future__ import annotations

import dataclasses
import re
import struct
from dataclasses import dataclass

from cryptography.exceptions import InvalidSignature
from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey, Ed25519PublicKey

from dynenv_ros.security.keys import key_id as key_id_of

DOMAIN = b"dynenv_msgs/WeightsAnnouncement/1"
SIGNATURE_BYTES = 64
# The message's bounds (msg_defs/msg/WeightsAnnouncement.msg): checked here too, so the core refuses what the wire
# type would, whatever carried it.
MAX_RUN_ID, MAX_METADATA, MAX_FRAME_ID = 128, 8192, 256
_SHA256 = re.compile(r"[0-9a-f]{64}")
_KEY_ID = re.compile(r"[0-9a-f]{16}")


class Refused(ValueError):
    """An announcement refused; ``reason`` is the diagnostics key (e.g. ``bad_signature``), the message one line."""

    def __init__(self, reason: str, message: str) -> None:
        super().__init__(message)
        self.reason = reason


@dataclass(frozen=True)
class Announcement:
    """The fields of a WeightsAnnouncement (header stamp as seconds and nanoseconds)."""
    run_id: str
    version: int
    size: int
    sha256: str
    metadata_json: str
    stamp_sec: int = 0
    stamp_nanosec: int = 0
    frame_id: str = ""
    key_id: str = ""
    signature: bytes = b""

    @property
    def stamp_ns(self) -> int:
        return self.stamp_sec * 1_000_000_000 + self.stamp_nanosec


def canonical_bytes(announcement: Announcement) -> bytes:
    """What is signed: every field but the signature, length-prefixed (module docstring)."""
    a = announcement
    parts = (DOMAIN, struct.pack(">iI", a.stamp_sec, a.stamp_nanosec), a.frame_id.encode(), a.run_id.encode(),
             struct.pack(">I", a.version), struct.pack(">Q", a.size), a.sha256.encode(), a.metadata_json.encode(),
             a.key_id.encode())
    return b"".join(struct.pack(">I", len(p)) + p for p in parts)


def sign(announcement: Announcement, private_key: Ed25519PrivateKey) -> Announcement:
    """The announcement with its signer's ``key_id`` and the signature over its canonical bytes."""
    unsigned = dataclasses.replace(announcement, key_id=key_id_of(private_key.public_key()), signature=b"")
    return dataclasses.replace(unsigned, signature=private_key.sign(canonical_bytes(unsigned)))


def check_fields(announcement: Announcement, max_bytes: int) -> None:
    """Refused (reason ``empty_sha256``, ``oversized`` or ``malformed``) unless the fields are well formed and the
    announced size is within ``max_bytes``: checks that need no key and happen before any fetch."""
    a = announcement
    if not a.sha256:
        raise Refused("empty_sha256", "sha256 is empty")
    if not _SHA256.fullmatch(a.sha256):
        raise Refused("malformed", f"sha256 {a.sha256[:70]!r} is not 64 lowercase hex characters")
    if not 1 <= a.size <= max_bytes:
        raise Refused("oversized" if a.size > max_bytes else "malformed",
                      f"size {a.size} bytes is outside 1..{max_bytes}")
    if not a.run_id or len(a.run_id) > MAX_RUN_ID:
        raise Refused("malformed", f"run_id must have 1..{MAX_RUN_ID} characters")
    if not 1 <= a.version < 2**32:
        raise Refused("malformed", f"version {a.version} is outside 1..2^32-1")
    if len(a.metadata_json) > MAX_METADATA or len(a.frame_id) > MAX_FRAME_ID:
        raise Refused("malformed", "metadata_json or frame_id longer than the message allows")
    if a.stamp_sec < 0 or not 0 <= a.stamp_nanosec < 1_000_000_000:
        raise Refused("malformed", f"stamp {a.stamp_sec}.{a.stamp_nanosec:09d} is not a valid wall-clock time")


def verify(announcement: Announcement, trusted: dict[str, Ed25519PublicKey]) -> None:
    """Refused (``untrusted_key``, ``bad_signature``) unless a trusted key signed exactly these fields."""
    a = announcement
    if not _KEY_ID.fullmatch(a.key_id) or a.key_id not in trusted:
        raise Refused("untrusted_key", f"signed by key {a.key_id[:16] or '(none)'!s}, which is not trusted")
    if len(a.signature) != SIGNATURE_BYTES:
        raise Refused("bad_signature", f"signature of {len(a.signature)} bytes, expected {SIGNATURE_BYTES}")
    try:
        trusted[a.key_id].verify(bytes(a.signature), canonical_bytes(a))
    except InvalidSignature:
        raise Refused("bad_signature", f"signature does not match key {a.key_id} (forged or altered)") from None
