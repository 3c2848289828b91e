"""Assembling an announced policy file from chunks, in order, into a buffer of exactly the announced size, and
checking it against the signed SHA-256 before anyone reads it.

The size was checked against the receiver's bound before the buffer exists, and no chunk may write past it, so a
server (genuine or forged) can cost the receiver the announced size and one chunk, never more. A chunk at the wrong
offset or of the wrong length is refused at once (``ChunkRefused``); a complete file whose hash differs raises
``Refused('hash_mismatch')``: it was damaged, or a forged server answered first.
"""
from __future__ import annotations

import hashlib

from dynenv_ros.security.weights_signing import Refused

CHUNK_BYTES = 1 << 20          # FetchWeights.Response.data's bound


class ChunkRefused(ValueError):
    """A chunk that does not continue the file (one line)."""


class Download:
    """One announced file: ``next_range`` says what to ask for, ``add`` files the answer, ``finish`` checks it."""

    def __init__(self, size: int, sha256: str, chunk_bytes: int = CHUNK_BYTES) -> None:
        if size < 1 or not 1 <= chunk_bytes <= CHUNK_BYTES:
            raise ValueError(f"size {size} and chunk {chunk_bytes} must be positive (chunk at most {CHUNK_BYTES})")
        self.size, self.sha256, self.chunk_bytes = size, sha256, chunk_bytes
        self.buffer = bytearray(size)
        self.received = 0
        self._hash = hashlib.sha256()

    @property
    def complete(self) -> bool:
        return self.received == self.size

    def next_range(self) -> tuple[int, int]:
        """(offset, length) of the next chunk to ask for."""
        return self.received, min(self.chunk_bytes, self.size - self.received)

    def add(self, offset: int, data: bytes | bytearray | memoryview) -> None:
        """File the chunk answering ``next_range``; ChunkRefused if it does not."""
        expected_offset, expected_length = self.next_range()
        if offset != expected_offset or len(data) != expected_length:
            raise ChunkRefused(f"chunk at {offset} of {len(data)} bytes, expected {expected_length} bytes at "
                               f"{expected_offset}")
        self.buffer[offset:offset + expected_length] = data
        self._hash.update(data)
        self.received += expected_length

    def finish(self) -> bytes:
        """The file's bytes once complete and matching the signed SHA-256 (the buffer is released)."""
        if not self.complete:
            raise ChunkRefused(f"{self.received} of {self.size} bytes received")
        digest = self._hash.hexdigest()
        if digest != self.sha256:
            self.buffer = bytearray()
            raise Refused("hash_mismatch", f"the fetched bytes hash to {digest[:12]}, not the signed "
                                           f"{self.sha256[:12]} (damaged, or a forged server answered)")
        data, self.buffer = bytes(self.buffer), bytearray()
        return data
