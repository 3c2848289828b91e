"""What pretraining runs: the robot-sequences of a split as tensors, the agent's forward pass over them from the zero
(or, ``--privileged-seeding``, a pose-seeded) recurrent state, and the localization + reconstruction loss."""
from __future__ import annotations

from typing import Any, Mapping, Sequence

import numpy as np
import torch

from dynenv_ros.learning.algo.auxiliary import self_supervised_losses
from dynenv_ros.learning.algo.policy import run_sequence
from dynenv_ros.learning.pretrain.data import OBS_KEYS, Split

UNIT_METRES = 5.2                    # DynEnv's normalised unit (520 px at 1 px = 1 cm)
SEED_NOISE = 0.02                    # DynEnv's pose-seeding noise, in its normalised units


class PoseSeeder(torch.nn.Module):
    """DynEnv's ``LSTMLayer.set_state``: the localization LSTM's cell state c = tanh(Linear(6→D)(pose))."""

    def __init__(self, feature_size: int = 64) -> None:
        super().__init__()
        self.linear = torch.nn.Linear(6, feature_size)

    def forward(self, pose: torch.Tensor) -> torch.Tensor:
        return torch.tanh(self.linear(pose))

    def to_meta(self) -> dict[str, Any]:
        return {"weight": self.linear.weight.detach().tolist(), "bias": self.linear.bias.detach().tolist()}

    @classmethod
    def from_meta(cls, value: Mapping[str, Any]) -> "PoseSeeder":
        weight = torch.tensor(value["weight"], dtype=torch.float32)
        seeder = cls(weight.shape[0])
        with torch.no_grad():
            seeder.linear.weight.copy_(weight)
            seeder.linear.bias.copy_(torch.tensor(value["bias"], dtype=torch.float32))
        return seeder


def seeding_noise(shape: Sequence[int], generator: torch.Generator) -> torch.Tensor:
    """DynEnv's N(0, 0.02²) in its normalised units, in ours: σ = 0.104 m on x, y, 0.02 on cos/sin."""
    scale = torch.tensor([SEED_NOISE * UNIT_METRES] * 2 + [SEED_NOISE] * 4)
    return torch.randn(tuple(shape), generator=generator) * scale


def robot_sequences(split: Split) -> dict[str, torch.Tensor]:
    """Every array as a tensor with leading (T, B) axes, B = S·A robot-sequences (sequence-major)."""
    out = {}
    for key, value in split.arrays.items():
        moved = np.moveaxis(value, 1, 0)                            # (T, S, A, ...)
        out[key] = torch.from_numpy(np.ascontiguousarray(moved.reshape(moved.shape[0], -1, *moved.shape[3:])))
    return out


def _batch(data: Mapping[str, torch.Tensor], rows: torch.Tensor) -> tuple[dict, dict]:
    obs = {k: data[k][:, rows] for k in OBS_KEYS}
    targets = {k: data[k][:, rows] for k in ("pose", "ball", "robots", "ball_known", "robots_known")}
    return obs, targets


def initial_state(agent: Any, pose0: torch.Tensor, seeder: PoseSeeder | None,
                  generator: torch.Generator | None) -> tuple[torch.Tensor, ...]:
    """The zero recurrent state of B robots; with a seeder, the localization cell seeded from the noisy pose."""
    state = list(agent.initial_state(pose0.shape[0]))
    if seeder is not None:
        noise = seeding_noise(pose0.shape, generator) if generator is not None else 0.0
        state[1] = seeder(pose0 + noise)
    return tuple(state)


def forward(agent: Any, obs: Mapping[str, torch.Tensor], pose0: torch.Tensor, seeder: PoseSeeder | None,
            generator: torch.Generator | None) -> Any:
    T, B = obs["game"].shape[:2]
    state = initial_state(agent, pose0, seeder, generator)
    return run_sequence(agent, obs, state, torch.zeros(T, B, dtype=torch.bool))


def losses(out: Any, targets: Mapping[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    parts = self_supervised_losses(out, targets, use_localization=True, use_reconstruction=True)
    parts["loss"] = parts["localization"] + parts["reconstruction"]
    return parts
