"""The driving agent's actions: what its heads output, how they become the commands of ``dynenv_msgs/Action``
(throttle, brake, steering), their log-probabilities, and the checks a policy node runs before a driving policy acts.

Two action modes, as the simulator's ``action_mode`` (docs/driving.md, "Actions"):

- ``discrete``: the original's ``MultiDiscrete([3, 3])`` — two categorical heads of 3 logits, acceleration (0
  reverse, 1 brake, 2 gas) and steering (0 right, 1 straight, 2 left). A choice becomes its command with
  ``driving.cars.discrete_action`` (the nine commands the simulator accepts in discrete mode).
- ``continuous``: one 3-dimensional Gaussian over the *normalised* command u = [throttle, brake, steering / limit]
  (each dimension with its own learned log standard deviation, its mean squashed into the bounds by a tanh), sampled
  and then clipped to the bounds ``CONTINUOUS_LOW`` / ``CONTINUOUS_HIGH`` = [−1, 0, −1] / [1, 1, 1]; the command is
  [u0, u1, u2 · limit]. The network never needs the steering limit (a config value): the node scales.

Log-probabilities of the continuous head are those of the action actually executed, a *clipped* Gaussian
(``ClippedNormal``): inside the bounds the Gaussian's density, on a bound the probability mass the Gaussian puts
beyond it (log Φ, computed with ``torch.special.log_ndtr`` so far tails stay finite). The density at a clipped value
(what an unclipped Gaussian's ``log_prob`` gives) would be wrong exactly where the policy presses a pedal fully or
steers at the limit. Its entropy is the underlying Gaussian's (the clipped variable's has no closed form).
"""
from __future__ import annotations

import math
from typing import Any, cast

import numpy as np
import torch
from torch.distributions import Categorical, Normal

from dynenv_ros.core.action_draws import Gaussian, draw_actions

ACTION_MODES = ("discrete", "continuous")
ACCELERATION_CHOICES, STEERING_CHOICES = 3, 3
CONTINUOUS_LOW = (-1.0, 0.0, -1.0)             # normalised [throttle, brake, steering / limit]
CONTINUOUS_HIGH = (1.0, 1.0, 1.0)
CONTINUOUS_SIZE = 3
INITIAL_STD = (0.5, 0.2, 0.5)
# Where an untrained continuous head's mean starts (normalised): no throttle, brake almost released, straight. A head
# starting at its bounds' centre (brake 0.5) brakes as hard as full throttle drives (``cars.brake_factor`` = 2), so a
# car hardly ever moves and no reward reaches the learner: PPO learnt nothing in the tiny driving task from there
# (test_learning_driving), and learns it from here.
INITIAL_COMMAND = (0.0, 0.02, 0.0)
BRAKE_COMMAND = (0.0, 1.0, 0.0)                 # what a car does without an action, and the fallback
BOUND_TOLERANCE = 1e-5


def check_action_mode(action_mode: Any) -> str:
    if action_mode not in ACTION_MODES:
        raise ValueError(f"action_mode must be 'discrete' or 'continuous', got {action_mode!r}")
    return cast(str, action_mode)


class ClippedNormal:
    """One dimension of a Gaussian whose samples are clipped to [low, high] (module docstring). Batch-shaped like
    ``loc``; ``log_prob``, ``entropy`` and ``sample`` follow ``torch.distributions`` (what the learner calls)."""

    def __init__(self, loc: torch.Tensor, scale: torch.Tensor, low: float, high: float) -> None:
        self.loc, self.scale, self.low, self.high = loc, scale, float(low), float(high)
        self.normal = Normal(loc, scale)

    @property
    def mean(self) -> torch.Tensor:
        return self.loc.clamp(self.low, self.high)

    @property
    def stddev(self) -> torch.Tensor:
        return self.scale

    def sample(self, sample_shape: torch.Size = torch.Size()) -> torch.Tensor:
        with torch.no_grad():
            sample: torch.Tensor = self.normal.sample(sample_shape).clamp(self.low, self.high)
            return sample

    def log_prob(self, value: torch.Tensor) -> torch.Tensor:
        value = torch.as_tensor(value, dtype=self.loc.dtype, device=self.loc.device)
        inside = self.normal.log_prob(value.clamp(self.low, self.high))
        below = torch.special.log_ndtr((self.low - self.loc) / self.scale)     # P(sample ≤ low)
        above = torch.special.log_ndtr((self.loc - self.high) / self.scale)    # P(sample ≥ high)
        return torch.where(value <= self.low, below, torch.where(value >= self.high, above, inside))

    def entropy(self) -> torch.Tensor:
        entropy: torch.Tensor = self.normal.entropy()
        return entropy


def distributions(action_mode: str, acceleration: torch.Tensor | None, steering: torch.Tensor | None,
                  command: torch.Tensor | None) -> list[Any]:
    """One distribution per action dimension: discrete, two ``Categorical`` (acceleration, steering); continuous,
    three ``ClippedNormal`` (throttle, brake, steering / limit) of ``command`` (..., 6) = [mean × 3, log_std × 3]."""
    if action_mode == "discrete":
        return [Categorical(logits=acceleration), Categorical(logits=steering)]
    head = cast(torch.Tensor, command)
    return [ClippedNormal(head[..., d], head[..., CONTINUOUS_SIZE + d].exp(), CONTINUOUS_LOW[d],
                          CONTINUOUS_HIGH[d]) for d in range(CONTINUOUS_SIZE)]


def _finite_rows(*tensors: torch.Tensor) -> torch.Tensor:
    finite = torch.ones(tensors[0].shape[0], dtype=torch.bool)
    for tensor in tensors:
        finite &= torch.isfinite(tensor.reshape(tensor.shape[0], -1)).all(-1)
    return finite


def sample_actions(step: Any, action_mode: str, generator: torch.Generator, greedy: bool
                   ) -> tuple[np.ndarray, np.ndarray]:
    """The network's actions from either runtime's outputs — (B, 2) acceleration and steering indices, or (B, 3)
    the clipped normalised command — and (B,) True where that car's outputs (recurrent state included) were all
    finite; a car with a non-finite output is sampled from zeros (so it cannot stop the others' sampling) and
    reported, for the caller to brake it. The generator is drawn from in the same order whatever the values
    (``core.action_draws``; the continuous head's noise in float64, all three dimensions at once)."""
    state = [torch.as_tensor(s) for s in step.state]
    heads: list[torch.Tensor | Gaussian] = []
    if action_mode == "discrete":
        logits = [torch.as_tensor(step.acceleration), torch.as_tensor(step.steering)]
        finite = _finite_rows(*logits, *state)
        for values in logits:
            heads.append(torch.softmax(torch.where(finite.unsqueeze(-1), values, torch.zeros_like(values)), dim=-1))
    else:
        command = torch.as_tensor(step.command).double()
        finite = _finite_rows(command, *state)
        command = torch.where(finite.unsqueeze(-1), command, torch.zeros_like(command))
        heads.append(Gaussian(command[:, :CONTINUOUS_SIZE], command[:, CONTINUOUS_SIZE:].exp(),
                              torch.tensor(CONTINUOUS_LOW, dtype=torch.float64),
                              torch.tensor(CONTINUOUS_HIGH, dtype=torch.float64), noise_dtype=torch.float64))
    columns = draw_actions(heads, generator, greedy)
    # discrete: one index per head; continuous: the one Gaussian's (B, 3) draw
    actions = torch.stack([c.double() for c in columns], dim=-1) if action_mode == "discrete" else columns[0]
    chosen = actions.numpy()
    usable = finite.numpy() & np.isfinite(chosen).all(-1)
    return chosen, usable


def commands(actions: np.ndarray, action_mode: str, max_yaw_rate: float) -> np.ndarray:
    """(B, 3) [throttle, brake, steering rad/s] of the network's actions (``sample_actions``): a discrete choice as
    ``driving.cars.discrete_action`` makes it (bit for bit the command the simulator expects), a continuous one
    scaled by the steering limit."""
    actions = np.asarray(actions, np.float64)
    if action_mode == "discrete":
        from dynenv_ros.driving.cars import discrete_action
        out = []
        for acceleration, steering in actions:
            c = discrete_action(int(acceleration), int(steering), max_yaw_rate)
            out.append((c.throttle, c.brake, c.steering))
        return np.array(out, np.float64).reshape(-1, 3)
    scaled: np.ndarray = actions * np.array([1.0, 1.0, max_yaw_rate])
    return scaled


def log_probs(step: Any, actions: np.ndarray, action_mode: str) -> np.ndarray:
    """(B,) log-probability of the network's actions (``sample_actions``) under either runtime's outputs: the sum
    over the heads, as the learner scores them (``distributions``); NaN where an output was not finite."""
    taken = torch.as_tensor(np.asarray(actions, np.float64))
    if action_mode == "discrete":
        outputs = (torch.as_tensor(step.acceleration, dtype=torch.float64),
                   torch.as_tensor(step.steering, dtype=torch.float64))
        dists = distributions("discrete", *outputs, None)
        taken = taken.long().clamp(0, 2)
    else:
        dists = distributions("continuous", None, None, torch.as_tensor(step.command, dtype=torch.float64))
    total = sum(dist.log_prob(taken[:, d]) for d, dist in enumerate(dists))
    result: np.ndarray = total.numpy()
    return result


def command_problem(command: np.ndarray, action_mode: str, max_yaw_rate: float) -> str:
    """Why the simulator would refuse one [throttle, brake, steering] command ('' if it would not); discrete mode
    accepts only the nine commands of ``discrete_action``."""
    throttle, brake, steering = (float(v) for v in command)
    for name, value, low, high in (("throttle", throttle, -1.0, 1.0), ("brake", brake, 0.0, 1.0),
                                   ("steering", steering, -max_yaw_rate, max_yaw_rate)):
        if not math.isfinite(value) or not low - BOUND_TOLERANCE <= value <= high + BOUND_TOLERANCE:
            return f"{name}={value} outside [{low:.6g}, {high:.6g}]"
    if action_mode == "discrete":
        from dynenv_ros.driving.cars import discrete_action
        nine = [discrete_action(a, s, max_yaw_rate) for a in range(3) for s in range(3)]
        if not any(abs(c.throttle - throttle) <= BOUND_TOLERANCE and abs(c.brake - brake) <= BOUND_TOLERANCE
                   and abs(c.steering - steering) <= BOUND_TOLERANCE for c in nine):
            return f"({throttle:.6g}, {brake:.6g}, {steering:.6g}) is not one of the nine discrete commands"
    return ""


def output_shapes(action_mode: str, batch: int) -> dict[str, tuple[int, ...]]:
    """The action outputs' names and shapes of a batch (the ``PolicyStep`` fields)."""
    if action_mode == "discrete":
        return {"acceleration": (batch, ACCELERATION_CHOICES), "steering": (batch, STEERING_CHOICES)}
    return {"command": (batch, 2 * CONTINUOUS_SIZE)}
