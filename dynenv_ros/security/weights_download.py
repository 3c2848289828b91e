"""Assembling an announced policy file from chunks that may come from anyone, into a buffer of exactly the announced
size, and checking it against the signed SHA-256 before anyone reads it.

The file is cut into chunks of ``CHUNK_BYTES`` (the last one shorter). Its **manifest** is the chunks' SHA-256
digests, concatenated (32 bytes each); the announcement signs the file's SHA-256 and the manifest's
(``security.weights_source``). Chunks reach a node two ways (``ros.weights_follower``):

- **samples of the trainer's blob topic**, which any process may also publish on. Each sample is placed by what it
  is, not by what it claims: a sample whose SHA-256 is the signed manifest digest is the manifest, one whose SHA-256
  is a chunk's digest in the manifest is that chunk (``offer``). Everything else is refused (``SampleRefused``) and
  cannot displace a genuine chunk, since nothing is written until the bytes match. A file of one chunk needs no
  manifest: its chunk's digest is the file's, signed.
- **answers of the trainer's fetch service** by offset and length (``add``), which a faster server may answer
  instead. A chunk whose digest is known is checked at once (``Refused('hash_mismatch')``); before the manifest
  is known (a file of several chunks whose manifest sample has not arrived) it is kept as unverified, checked when
  the manifest arrives or with the whole file.

``finish`` checks the whole file against the signed SHA-256 in every case; a mismatch drops the unverified chunks
(verified ones stay) so only they are fetched again. The buffer is allocated once, at the announced size, which was
checked against the receiver's bound before: a sender, genuine or forged, can cost the receiver the announced size
and the sample being checked, never more.
"""
from __future__ import annotations

import hashlib

from dynenv_ros.security.weights_signing import Refused

CHUNK_BYTES = 1 << 20          # FetchWeights.Response.data's bound: a service answer or a blob sample
DIGEST_BYTES = 32
MISSING, UNVERIFIED, VERIFIED = 0, 1, 2


class ChunkRefused(ValueError):
    """A service answer that does not continue the file (one line)."""


class SampleRefused(ValueError):
    """A blob sample that is no part of the file wanted; ``reason``: ``oversized`` (longer than a chunk),
    ``unverifiable`` (no manifest yet to check a chunk against), ``unmatched`` (bytes of no chunk of this file)."""

    def __init__(self, reason: str, message: str) -> None:
        super().__init__(message)
        self.reason = reason


def chunk_count(size: int, chunk_bytes: int = CHUNK_BYTES) -> int:
    return -(-size // chunk_bytes)


def manifest(data: bytes, chunk_bytes: int = CHUNK_BYTES) -> bytes:
    """The chunks' SHA-256 digests, concatenated: what the trainer publishes first and signs the digest of."""
    view = memoryview(data)
    return b"".join(hashlib.sha256(view[i:i + chunk_bytes]).digest() for i in range(0, len(data), chunk_bytes))


class Download:
    """One announced file: chunks in from either route, ``next_range`` for the fetch service, ``finish`` checks it."""

    def __init__(self, size: int, sha256: str, manifest_sha256: str = "", chunk_bytes: int = CHUNK_BYTES) -> None:
        if size < 1 or not 1 <= chunk_bytes <= CHUNK_BYTES:
            raise ValueError(f"size {size} and chunk {chunk_bytes} must be positive (chunk at most {CHUNK_BYTES})")
        self.size, self.sha256, self.manifest_sha256, self.chunk_bytes = size, sha256, manifest_sha256, chunk_bytes
        self.chunks = chunk_count(size, chunk_bytes)
        self.buffer = bytearray(size)
        self.state = bytearray(self.chunks)             # MISSING, UNVERIFIED or VERIFIED per chunk
        self.digests: list[bytes] | None = [bytes.fromhex(sha256)] if self.chunks == 1 else None
        self.dropped = 0                                 # unverified chunks found to be junk (fetch answers)

    # -- where things stand ---------------------------------------------------------------------------------------
    @property
    def complete(self) -> bool:
        return MISSING not in self.state

    @property
    def received(self) -> int:
        """Bytes held (verified or not)."""
        return sum(self._length(i) for i in range(self.chunks) if self.state[i] != MISSING)

    @property
    def verified(self) -> int:
        return self.state.count(VERIFIED)

    def _length(self, index: int) -> int:
        return min(self.chunk_bytes, self.size - index * self.chunk_bytes)

    def holds(self, offset: int) -> bool:
        """The chunk at ``offset`` is held already (verified or not)."""
        return self.state[offset // self.chunk_bytes] != MISSING

    def next_range(self) -> tuple[int, int]:
        """(offset, length) of the first chunk not held: what to ask the fetch service for."""
        index = self.state.index(MISSING) if not self.complete else 0
        return index * self.chunk_bytes, self._length(index)

    # -- the blob topic: placed by content -------------------------------------------------------------------------
    def offer(self, data: bytes | bytearray | memoryview) -> str:
        """File a blob sample by what its bytes are: returns ``manifest``, ``chunk`` or ``duplicate`` (a chunk held
        and verified already); SampleRefused otherwise. Nothing is written unless the bytes match a signed digest."""
        if len(data) > max(self.chunk_bytes, DIGEST_BYTES * self.chunks):
            raise SampleRefused("oversized", f"a sample of {len(data)} bytes, longer than a chunk")
        digest = hashlib.sha256(data).digest()
        if self.digests is None:
            if digest.hex() == self.manifest_sha256 and len(data) == DIGEST_BYTES * self.chunks:
                self._take_manifest(bytes(data))
                return "manifest"
            raise SampleRefused("unverifiable", "a sample before the manifest: no digest to check it against")
        indices = [i for i, d in enumerate(self.digests) if d == digest and self._length(i) == len(data)]
        if not indices:
            if digest.hex() == self.manifest_sha256:
                return "duplicate"
            raise SampleRefused("unmatched", f"a sample of {len(data)} bytes that is no chunk of the file wanted")
        if all(self.state[i] == VERIFIED for i in indices):
            return "duplicate"
        for i in indices:                               # equal chunks (runs of zeros) are one digest
            offset = i * self.chunk_bytes
            self.buffer[offset:offset + len(data)] = data
            self.state[i] = VERIFIED
        return "chunk"

    def _take_manifest(self, data: bytes) -> None:
        """The manifest arrived: check the chunks held unverified, drop those that do not match."""
        self.digests = [data[i:i + DIGEST_BYTES] for i in range(0, len(data), DIGEST_BYTES)]
        for i in range(self.chunks):
            if self.state[i] == UNVERIFIED:
                self._check_held(i)

    def _check_held(self, index: int) -> None:
        offset = index * self.chunk_bytes
        if hashlib.sha256(self.buffer[offset:offset + self._length(index)]).digest() == self.digests[index]:
            self.state[index] = VERIFIED
        else:
            self.state[index] = MISSING
            self.dropped += 1

    # -- the fetch service: placed by offset -----------------------------------------------------------------------
    def add(self, offset: int, data: bytes | bytearray | memoryview) -> None:
        """File the answer to ``next_range``: ChunkRefused if it is not that range; Refused('hash_mismatch') if
        the chunk's digest is known and differs (junk from a server that answered first)."""
        expected_offset, expected_length = self.next_range()
        if offset != expected_offset or len(data) != expected_length or self.complete:
            raise ChunkRefused(f"chunk at {offset} of {len(data)} bytes, expected {expected_length} bytes at "
                               f"{expected_offset}")
        index = offset // self.chunk_bytes
        if self.digests is not None and hashlib.sha256(data).digest() != self.digests[index]:
            raise Refused("hash_mismatch", f"the chunk at {offset} is not the signed one (a forged server "
                                           "answered first, or it was damaged)")
        self.buffer[offset:offset + expected_length] = data
        self.state[index] = VERIFIED if self.digests is not None else UNVERIFIED

    # -- the whole file ----------------------------------------------------------------------------------------------
    def finish(self) -> bytes:
        """The file's bytes once complete and matching the signed SHA-256 (the buffer is released). On a mismatch
        the unverified chunks are dropped and Refused('hash_mismatch') raised: fetch them again."""
        if not self.complete:
            raise ChunkRefused(f"{self.received} of {self.size} bytes held")
        digest = hashlib.sha256(self.buffer).hexdigest()
        if digest != self.sha256:
            unverified = [i for i in range(self.chunks) if self.state[i] == UNVERIFIED]
            for i in unverified or range(self.chunks):  # all verified and still wrong: a trainer's inconsistency
                self.state[i] = MISSING
            self.dropped += len(unverified)
            raise Refused("hash_mismatch", f"the fetched bytes hash to {digest[:12]}, not the signed "
                                           f"{self.sha256[:12]} (damaged, or a forged server answered)")
        data, self.buffer = bytes(self.buffer), bytearray()
        return data
