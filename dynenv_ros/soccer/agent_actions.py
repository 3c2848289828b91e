"""The soccer agent's actions: the discrete head's index <-> radians conversion (written once, here), how either
runtime's outputs become [walk, turn, kick, head_yaw_delta] actions (``sample_actions``), their
log-probabilities (``behaviour_log_probs``) and why the simulator would refuse one (``action_problem``).

The head turns in rad per period. A discrete head has ``2·units + 1`` choices of ``step`` rad each, centred:
index i is ``(i - units) · step`` rad, and a turn maps back to the nearest index (``head_index``, clipped to
0..2·units). Callers give the step they hold — a policy its ``head_max / units``, the simulator its
``motion.head_step`` — so each conversion is bit for bit what it was where it was written before (issue 40).
"""
from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

import numpy as np

from dynenv_ros.core.action_draws import Gaussian, draw_actions

if TYPE_CHECKING:      # torch is imported where a policy's outputs are read: the soccer world loads without it
    import torch

WALK_CHOICES, TURN_CHOICES, KICK_CHOICES = 5, 3, 3     # Action.msg's soccer choices


def head_radians(index: Any, units: int, step: float | None = None, *, head_max: float | None = None) -> Any:
    """Head turn (rad) of a discrete head's index 0..2·units (a number, numpy array or tensor): ``(index - units)
    · step``. Given ``head_max`` instead of the step: ``(index - units) · head_max / units``, multiplied before it
    divides — how dynenv-eval has always turned a checkpoint's index into radians (the two orders differ in the
    last bit for some values)."""
    if (step is None) == (head_max is None):
        raise ValueError("give one of the head's step and its head_max")
    if head_max is not None:
        return (index - units) * head_max / units
    return (index - units) * step


def head_index(radians: Any, units: int, step: float, dtype: Any = np.float64) -> Any:
    """The discrete head's index nearest to a head turn (rad), clipped to 0..2·units, as float64 (rounding half to
    even; NaN stays NaN, for the caller to convert as it needs). ``dtype`` None: the turn divided in its own type
    (a NumPy float32 scalar in float32, a Python float in float64), the index then of that type — how the teachers
    have always rounded a scripted player's turn (``envs.teacher``)."""
    turn = radians if dtype is None else np.asarray(radians, dtype)
    return np.clip(np.rint(turn / step) + units, 0, 2 * units)


def sample_actions(step: Any, head_mode: str, head_units: int | None, head_max: float,
                   generator: torch.Generator, greedy: bool) -> tuple[np.ndarray, np.ndarray]:
    """(B, 4) [walk, turn, kick, head_yaw_delta in rad] from either runtime's outputs, and (B,) True where that
    robot's outputs were all finite. A robot with a NaN or infinite output gets zero logits (so it cannot stop the
    others' sampling: ``torch.multinomial`` refuses a batch with one bad row) and is reported, for the caller to
    replace its action. The generator is drawn from in the same order whatever the values
    (``core.action_draws``)."""
    import torch
    logits = [torch.as_tensor(x) for x in (step.walk, step.turn, step.kick)]
    head = torch.as_tensor(step.head)
    state = [torch.as_tensor(x) for x in step.state]
    finite = torch.ones(head.shape[0], dtype=torch.bool)
    for tensor in logits + [head] + state:
        finite &= torch.isfinite(tensor.reshape(tensor.shape[0], -1)).all(-1)
    heads: list[torch.Tensor | Gaussian] = []
    categorical = logits + ([head] if head_mode == "discrete" else [])
    for values in categorical:
        values = torch.where(finite.unsqueeze(-1), values, torch.zeros_like(values))
        heads.append(torch.softmax(values, dim=-1))
    if head_mode != "discrete":
        values = torch.where(finite.unsqueeze(-1), head, torch.zeros_like(head))
        heads.append(Gaussian(values[:, 0], values[:, 1].exp(), -head_max, head_max))
    columns = draw_actions(heads, generator, greedy)
    if head_mode == "discrete":
        units = int(head_units or 0)
        columns[-1] = head_radians(columns[-1].double(), units, head_max / units)
    actions = torch.stack([c.double() for c in columns], dim=-1).numpy()
    finite &= torch.from_numpy(np.isfinite(actions).all(-1))
    return actions, finite.numpy()


def behaviour_log_probs(step: Any, actions: np.ndarray, head_mode: str, head_units: int | None,
                        head_max: float) -> np.ndarray:
    """(B,) log-probability of (B, 4) [walk, turn, kick, head rad] actions under either runtime's outputs — the sum
    over the action heads, as the learner's ``DynEnvAgent.distributions`` scores them (a discrete head's radians
    mapped back to its index; a continuous head's Gaussian at the executed, clipped value). Sent with each action
    (``Action.log_prob``) for the trainer's off-policy correction; NaN where an output was not finite."""
    import torch
    actions = np.asarray(actions, np.float64)
    total = np.zeros(actions.shape[0])
    for column, values in enumerate((step.walk, step.turn, step.kick)):
        logits = torch.as_tensor(values, dtype=torch.float64)
        index = torch.as_tensor(actions[:, column]).long().clamp(0, logits.shape[-1] - 1)
        total += torch.log_softmax(logits, -1).gather(-1, index[:, None])[:, 0].numpy()
    head = torch.as_tensor(step.head, dtype=torch.float64)
    if head_mode == "discrete":
        units = int(head_units or 0)
        index = torch.as_tensor(head_index(actions[:, 3], units, head_max / units)).long().clamp(0, 2 * units)
        total += torch.log_softmax(head, -1).gather(-1, index[:, None])[:, 0].numpy()
    else:
        normal = torch.distributions.Normal(head[:, 0], head[:, 1].exp())
        total += normal.log_prob(torch.as_tensor(actions[:, 3])).numpy()
    return total


def action_problem(action: np.ndarray, head_bound: float) -> str:
    """Why one [walk, turn, kick, head] action would be refused by the simulator ('' if it would not)."""
    walk, turn, kick, head = (float(v) for v in action)
    for name, value, count in (("walk", walk, WALK_CHOICES), ("turn", turn, TURN_CHOICES),
                               ("kick", kick, KICK_CHOICES)):
        if not (0 <= value < count and value == int(value)):
            return f"{name}={value} outside 0..{count - 1}"
    if not math.isfinite(head) or abs(head) > head_bound + 1e-6:
        return f"head_yaw_delta={head} rad beyond ±{head_bound:.4f}"
    return ""
