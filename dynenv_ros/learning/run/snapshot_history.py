"""The snapshot opponent's pool, as the learner sees it, so that a checkpoint can hold it.

Why: a run against its own past copies (``opponent: snapshot``, or the league's snapshot member) plays the pool of
the last ``snapshot_pool`` copies taken every ``snapshot_every_updates`` updates. The worlds that hold that pool (in
this process or in rollout workers) are not checkpointed, so before this a resumed run's pool was only the resumed
weights, and it took ``snapshot_pool × snapshot_every_updates`` updates to be what an unbroken run's was. The
learner takes the same copies (its weights at update 0 and at every multiple of ``snapshot_every_updates``), keeps
the last ``snapshot_pool`` in its checkpoints (``snapshot.<i>.<parameter>`` tensors beside the generator state),
and hands them back to the worlds on ``--resume``.
"""
from __future__ import annotations

from typing import Mapping

import numpy as np
import torch

PREFIX = "snapshot."


class SnapshotHistory:
    """The last ``pool`` copies of the policy's weights, taken at update 0 and every ``every`` updates."""

    def __init__(self, every: int, pool: int, states: list[dict[str, np.ndarray]] | None = None) -> None:
        self.every, self.pool = every, pool
        self.states: list[dict[str, np.ndarray]] = list(states or [])[-pool:]

    def take(self, agent: torch.nn.Module) -> None:
        """A copy of ``agent``'s weights now (CPU arrays: they travel to worker processes as they are)."""
        copy = {name: t.detach().cpu().numpy().copy() for name, t in agent.state_dict().items()}
        self.states = (self.states + [copy])[-self.pool:]

    def after_update(self, updates: int, agent: torch.nn.Module) -> None:
        if updates % self.every == 0:
            self.take(agent)

    def tensors(self) -> dict[str, torch.Tensor]:
        """The checkpoint's tensors: ``snapshot.<i>.<parameter>``, i = 0 the oldest."""
        return {f"{PREFIX}{i}.{name}": torch.from_numpy(value)
                for i, state in enumerate(self.states) for name, value in state.items()}

    @classmethod
    def from_checkpoint(cls, extra: Mapping[str, torch.Tensor], every: int, pool: int,
                        agent: torch.nn.Module) -> "SnapshotHistory":
        """The copies a checkpoint's extra tensors hold (none in a checkpoint from before they were kept). ValueError
        when a copy does not fit ``agent`` (another network's checkpoint)."""
        by_index: dict[int, dict[str, np.ndarray]] = {}
        for key, value in extra.items():
            if key.startswith(PREFIX):
                index, _, name = key[len(PREFIX):].partition(".")
                if not index.isdigit() or not name:
                    raise ValueError(f"checkpoint: snapshot tensor {key!r} is not snapshot.<i>.<parameter>")
                by_index.setdefault(int(index), {})[name] = value.detach().cpu().numpy()
        expected = {name: tuple(t.shape) for name, t in agent.state_dict().items()}
        for index, state in by_index.items():
            shapes = {name: tuple(v.shape) for name, v in state.items()}
            if shapes != expected:
                raise ValueError(f"checkpoint: snapshot {index} does not fit this run's network "
                                 f"({len(shapes)} tensors, the network has {len(expected)}, or their shapes differ)")
        return cls(every, pool, [by_index[i] for i in sorted(by_index)])
