"""The learner's weights in one block of shared memory, for the rollout workers on this machine to act with.

One writer (the learner, after each update) and any number of readers (the workers, before each rollout), with no
lock a dead process could leave held: a sequence counter that is odd while a write is under way (a seqlock). A
reader copies the weights while the counter is even and keeps the copy only if the counter and the version are
unchanged after it; otherwise it copies again. This relies on other processes seeing the writer's plain stores in
program order, which x86-64 guarantees (TSO), as on every machine this project runs on; on a weaker memory model a
torn copy would be possible.

Every floating-point tensor of the module's ``state_dict`` is carried (the agent, the curiosity heads, the pose
seeder): a worker's acting copy is the whole ``TrainingNetworks``, so privileged pose seeding acts with the learner's
seeder. Versions count the learner's updates; -1 means nothing was published yet.
"""
from __future__ import annotations

import time

import numpy as np
import torch

from dynenv_ros.core.shared_arrays import AttachedArrays, SharedArrays

_SEQUENCE, _VERSION = 0, 1


def _layout(module: torch.nn.Module) -> list[tuple[str, torch.Size, int, int]]:
    """(name, shape, offset, size) of every floating-point tensor of the state dict, in its order."""
    out, offset = [], 0
    for name, tensor in module.state_dict().items():
        if tensor.is_floating_point():
            out.append((name, tensor.shape, offset, tensor.numel()))
            offset += tensor.numel()
    return out


def pack(module: torch.nn.Module) -> tuple[np.ndarray, list[tuple[str, torch.Size, int, int]]]:
    """The module's floating-point state as one float32 vector (for a transport without shared memory: Ray)."""
    layout = _layout(module)
    state = module.state_dict()
    flat = np.empty(sum(size for *_, size in layout), np.float32)
    for name, _, offset, size in layout:
        flat[offset:offset + size] = state[name].detach().reshape(-1).to("cpu", torch.float32).numpy()
    return flat, layout


def unpack(flat: np.ndarray, module: torch.nn.Module) -> None:
    """``pack``'s vector back into a module of the same layout (ValueError if the layouts differ)."""
    layout = _layout(module)
    if flat.shape != (sum(size for *_, size in layout),):
        raise ValueError(f"packed weights hold {flat.size} values, the networks {sum(s for *_, s in layout)}: "
                         "built from different configs")
    _copy_into(module, flat if flat.flags.writeable else flat.copy(), layout)   # (Ray's arrays are read-only)


def _copy_into(module: torch.nn.Module, flat: np.ndarray, layout: list[tuple[str, torch.Size, int, int]]) -> None:
    with torch.no_grad():
        state = module.state_dict()
        for name, shape, offset, size in layout:
            state[name].copy_(torch.from_numpy(flat[offset:offset + size]).view(shape))


class SharedWeights:
    """Created by the learner from its module (``publish`` writes, ``names`` tells the workers where)."""

    def __init__(self, module: torch.nn.Module) -> None:
        self.layout = _layout(module)
        total = sum(size for *_, size in self.layout)
        self._shared = SharedArrays({"header": ((2,), np.dtype(np.int64)), "weights": ((total,), np.dtype(np.float32))})
        self.header, self.flat = self._shared.arrays["header"], self._shared.arrays["weights"]
        self.header[_VERSION] = -1

    @property
    def nbytes(self) -> int:
        return int(self.flat.nbytes)

    def names(self) -> dict[str, tuple[str, tuple[int, ...], str]]:
        return self._shared.names()

    def publish(self, module: torch.nn.Module, version: int) -> None:
        """Write ``module``'s weights (the layout it was created with) as ``version``."""
        state = module.state_dict()
        self.header[_SEQUENCE] += 1                      # odd: a write is under way
        for name, shape, offset, size in self.layout:
            tensor = state[name].detach()
            if tensor.shape != shape:
                raise ValueError(f"weights {name} have shape {tuple(tensor.shape)}, the shared layout {tuple(shape)}")
            self.flat[offset:offset + size] = tensor.reshape(-1).to("cpu", torch.float32).numpy()
        self.header[_VERSION] = version
        self.header[_SEQUENCE] += 1                      # even: complete

    def close(self) -> None:
        self.header = self.flat = None
        self._shared.close()


class AttachedWeights:
    """A worker's reader of ``SharedWeights``."""

    def __init__(self, names: dict[str, tuple[str, tuple[int, ...], str]], module: torch.nn.Module) -> None:
        self.layout = _layout(module)
        self._attached = AttachedArrays({key: names[key] for key in ("header", "weights")})
        self.header, self.flat = self._attached.arrays["header"], self._attached.arrays["weights"]
        expected = sum(size for *_, size in self.layout)
        if self.flat.size != expected:
            held = self.flat.size
            self.close()
            raise ValueError(f"shared weights hold {held} values, this worker's networks {expected}: "
                             "the learner and the worker were built from different configs")
        self._copy = np.empty_like(self.flat)

    def version(self) -> int:
        return int(self.header[_VERSION])

    def load_into(self, module: torch.nn.Module, newer_than: int, timeout: float = 60.0) -> int:
        """Copy the published weights into ``module`` if their version is above ``newer_than``; returns the version
        now in ``module`` (``newer_than`` when nothing newer was there). Waits up to ``timeout`` seconds for a
        first publication, or for a write under way to finish (TimeoutError after that)."""
        deadline = time.monotonic() + timeout
        while True:
            before = int(self.header[_SEQUENCE])
            version = int(self.header[_VERSION])
            if 0 <= version <= newer_than:
                return newer_than
            if version >= 0 and before % 2 == 0:
                np.copyto(self._copy, self.flat)
                if int(self.header[_SEQUENCE]) == before and int(self.header[_VERSION]) == version:
                    break
            if time.monotonic() > deadline:
                raise TimeoutError(f"no complete weights published within {timeout:.0f} s"
                                   + (" (a write never finished)" if version >= 0 else ""))
            time.sleep(0.01 if version < 0 else 0.0005)  # nothing yet, or a write is under way
        _copy_into(module, self._copy, self.layout)
        return version

    def close(self) -> None:
        self.header = self.flat = None
        self._attached.close()
