"""Numpy arrays in shared memory between the processes of one machine: the vector env's worlds and its worker
processes (``envs.vector``), the learner and its rollout workers (``learning.distributed``: rollout slots, the
weights block, the inference server's requests and answers). ``SharedArrays`` creates them (and unlinks them);
``AttachedArrays`` is another process's view of them, by their names."""
from __future__ import annotations

import math
import weakref
from multiprocessing import shared_memory
from typing import Any, Mapping

import numpy as np


def close_blocks(blocks: list[shared_memory.SharedMemory]) -> None:
    """Unmap blocks this process attached (their owner unlinks them)."""
    for block in blocks:
        try:
            block.close()
        except BufferError:      # someone still holds a view (copy=False); the mapping goes with the last view
            pass


def _release_blocks(blocks: list[shared_memory.SharedMemory]) -> None:
    close_blocks(blocks)
    for block in blocks:
        try:
            block.unlink()
        except FileNotFoundError:
            pass


class SharedArrays:
    """Named numpy arrays, one shared-memory block each, created (and unlinked) by this process: ``names()`` is
    what another process attaches them by. The blocks are unlinked on ``close`` or when the object goes, whatever
    happens in between (a failed creation included)."""

    def __init__(self, spec: Mapping[str, tuple[tuple[int, ...], np.dtype[Any]]]) -> None:
        self.blocks: dict[str, shared_memory.SharedMemory] = {}
        created: list[shared_memory.SharedMemory] = []      # the finalizer's list, filled as blocks are made
        self._finalizer = weakref.finalize(self, _release_blocks, created)
        try:
            for key, (shape, dtype) in spec.items():
                size = max(1, math.prod(shape) * np.dtype(dtype).itemsize)
                created.append(shared_memory.SharedMemory(create=True, size=size))
                self.blocks[key] = created[-1]
        except BaseException:
            self._finalizer()
            raise
        self.spec = spec
        self.arrays = {key: np.ndarray(shape, dtype, buffer=self.blocks[key].buf)
                       for key, (shape, dtype) in spec.items()}

    def names(self) -> dict[str, tuple[str, tuple[int, ...], str]]:
        """Each array's (block name, shape, dtype string)."""
        return {key: (self.blocks[key].name, shape, np.dtype(dtype).str) for key, (shape, dtype) in self.spec.items()}

    def close(self) -> None:
        self.arrays = {}
        self._finalizer()


class AttachedArrays:
    """The arrays of another process's ``SharedArrays``, attached by its ``names()``: the same memory. ``close``
    unmaps them here; their creator unlinks them."""

    def __init__(self, names: Mapping[str, tuple[str, tuple[int, ...], str]]) -> None:
        self._blocks: list[shared_memory.SharedMemory] = []
        self.arrays: dict[str, np.ndarray] = {}
        try:
            for key, (name, shape, dtype) in names.items():
                block = shared_memory.SharedMemory(name=name)
                self._blocks.append(block)
                self.arrays[key] = np.ndarray(shape, np.dtype(dtype), buffer=block.buf)
        except BaseException:
            self.close()
            raise

    def close(self) -> None:
        self.arrays = {}
        close_blocks(self._blocks)
        self._blocks = []
