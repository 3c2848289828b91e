"""How a rollout travels from a rollout worker to the learner: as a flat dict of named numpy arrays (``flatten`` /
``unflatten``), written into a slot of shared memory (``RolloutSlots``, worker processes on this machine) or shipped
through Ray's object store (``learning.distributed.ray_pool``), and joined with other workers' rollouts along the robot axis
(``join``).

Why a flat dict: it is the one form both transports carry without pickling anything per detection, and its spec
(names, shapes, dtypes) is all a slot needs to be allocated. The spec is taken from a worker's first rollout (the
worker's handshake), so every optional array (targets, teacher labels, the alive mask, privileged seed poses) is
carried exactly when the run makes it, with no second description of the rollout's shapes to keep in step.
"""
from __future__ import annotations

import math
from typing import Mapping

import numpy as np
import torch

from dynenv_ros.core.shared_arrays import AttachedArrays, SharedArrays
from dynenv_ros.learning.algo.experience import STEP_ARRAYS, Rollout

Spec = dict[str, tuple[tuple[int, ...], str]]
# Rollout fields that are optional (None or {} when the run does not make them); step arrays are always there.
_OPTIONAL = ("seed_pose", "teacher_actions", "teacher_driven", "alive")
# arrays whose robot axis is the first (the rest are (T or T+1, B, ...)): the start state, per-robot flags
_ROBOT_FIRST = ("seed_pose", "teacher_driven")


def flatten(rollout: Rollout) -> dict[str, np.ndarray]:
    """Every array of a rollout under a flat name: ``obs/<key>``, ``targets/<key>``, ``initial_state/<i>`` (the
    recurrent state as numpy), the step arrays and the optional ones the rollout has."""
    out: dict[str, np.ndarray] = {name: getattr(rollout, name) for name in STEP_ARRAYS}
    out.update({f"obs/{k}": v for k, v in rollout.obs.items()})
    out.update({f"targets/{k}": v for k, v in rollout.targets.items()})
    out.update({f"initial_state/{i}": s.detach().cpu().numpy() for i, s in enumerate(rollout.initial_state)})
    for name in _OPTIONAL:
        value = getattr(rollout, name)
        if value is not None:
            out[name] = value
    return out


def unflatten(arrays: Mapping[str, np.ndarray]) -> Rollout:
    """The rollout of ``flatten``'s dict; its arrays are the given ones (views of a slot stay views)."""
    def group(prefix: str) -> dict[str, np.ndarray]:
        return {k[len(prefix):]: v for k, v in arrays.items() if k.startswith(prefix)}
    states = group("initial_state/")
    initial_state = tuple(torch.from_numpy(np.ascontiguousarray(states[str(i)])) for i in range(len(states)))
    optional = {name: arrays[name] for name in _OPTIONAL if name in arrays}
    return Rollout(**{name: arrays[name] for name in STEP_ARRAYS}, obs=group("obs/"), initial_state=initial_state,
                   targets=group("targets/"), **optional)


def spec_of(arrays: Mapping[str, np.ndarray]) -> Spec:
    """Names → (shape, dtype string): what a slot must hold."""
    return {k: (tuple(int(n) for n in v.shape), np.dtype(v.dtype).str) for k, v in arrays.items()}


def spec_bytes(spec: Spec) -> int:
    return sum(math.prod(shape) * np.dtype(dtype).itemsize for shape, dtype in spec.values())


def join(rollouts: list[Rollout]) -> Rollout:
    """Several rollouts of equal length as one, their robots side by side (in the given order). One rollout is
    returned as it is (no copy)."""
    if len(rollouts) == 1:
        return rollouts[0]
    flats = [flatten(r) for r in rollouts]
    names = set(flats[0])
    for other in flats[1:]:
        if set(other) != names:
            raise ValueError(f"rollouts to join carry different arrays: {sorted(names ^ set(other))}")
    joined = {}
    for name in names:
        robot_first = name in _ROBOT_FIRST or name.startswith("initial_state/")
        joined[name] = np.concatenate([f[name] for f in flats], axis=0 if robot_first else 1)
    return unflatten(joined)


class RolloutSlots:
    """``count`` slots of shared memory, each holding one rollout of ``spec``: created (and unlinked on close) by the
    learner, attached by one worker, which writes a rollout into a free slot and names the slot to the learner."""

    def __init__(self, spec: Spec, count: int) -> None:
        if count < 1:
            raise ValueError(f"a worker needs at least one slot, got {count}")
        self.spec = spec
        self._slots = [SharedArrays({k: (shape, np.dtype(dtype)) for k, (shape, dtype) in spec.items()})
                       for _ in range(count)]

    def __len__(self) -> int:
        return len(self._slots)

    def names(self) -> list[dict[str, tuple[str, tuple[int, ...], str]]]:
        return [slot.names() for slot in self._slots]

    def read(self, index: int) -> Rollout:
        """The rollout in slot ``index``, its arrays views of the shared memory (valid until the slot is released)."""
        return unflatten(self._slots[index].arrays)

    def close(self) -> None:
        for slot in self._slots:
            slot.close()


class AttachedSlots:
    """A worker's side of its ``RolloutSlots``: the same blocks, attached by name."""

    def __init__(self, names: list[dict[str, tuple[str, tuple[int, ...], str]]]) -> None:
        self._slots: list[AttachedArrays] = []
        try:
            for slot in names:
                self._slots.append(AttachedArrays(slot))
        except BaseException:
            self.close()
            raise

    def __len__(self) -> int:
        return len(self._slots)

    def write(self, index: int, arrays: Mapping[str, np.ndarray]) -> None:
        """Copy a flattened rollout into slot ``index``; its names and shapes must be the slot's."""
        slot = self._slots[index].arrays
        if set(arrays) != set(slot):
            raise ValueError(f"rollout arrays differ from the slot's: {sorted(set(arrays) ^ set(slot))}")
        for key, value in arrays.items():
            if value.shape != slot[key].shape:
                raise ValueError(f"rollout array {key} has shape {value.shape}, the slot {slot[key].shape}")
            np.copyto(slot[key], value, casting="same_kind")

    def close(self) -> None:
        for slot in self._slots:
            slot.close()
        self._slots = []
