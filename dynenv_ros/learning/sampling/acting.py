"""How a collector's learning robots act: one acting forward per period (the value of every robot), sampled actions
and their log-probabilities (the teacher's actions where the teacher drives), and the recurrent state carried from
period to period, zeroed where an episode starts.

``LocalActing`` does it in this process with the collector's agent and generator, as the in-process trainer and a
rollout worker with ``inference: worker`` do; ``distributed.inference_server.ServerActing`` asks the inference
server, which holds the state and the generator for the worker and batches every worker's robots into one forward.
Both draw the actions with ``act_on``, from one generator per worker over that worker's rows, so for the same seed
and the same logits they draw the same actions.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable, Mapping, Protocol

import numpy as np
import torch
from torch import Tensor

from dynenv_ros.agent.network import DynEnvAgent, State
from dynenv_ros.learning.algo.policy import (action_log_prob, action_width, device_of, policy_step, reset_state,
                                             sample_actions)


@dataclass
class Acted:
    """One period's outcome for B robots: values (B,); actions (B, W) and log-probabilities (B,) unless only the
    value was asked (the bootstrap period); ``start_state``: the state the forward started from, when asked."""
    values: np.ndarray
    actions: np.ndarray | None = None
    log_probs: np.ndarray | None = None
    start_state: State | None = None


class Acting(Protocol):
    """What a collector acts through (``LocalActing``, ``ServerActing``)."""

    def seed(self, pose: np.ndarray) -> None:
        """Replace every robot's state by the pose seeder's state of ``pose`` (B, 6) (privileged seeding)."""

    def step(self, obs: Mapping[str, np.ndarray], starts: np.ndarray, last: bool, want_state: bool = False,
             teacher: np.ndarray | None = None, driven: np.ndarray | None = None) -> Acted:
        """One period of the B robots from their observations (robots leading) and the robots whose episode starts
        (their state is zeroed first). ``last``: the value only, the state not advanced (the bootstrap period;
        the next rollout acts on the same observation). ``teacher`` / ``driven`` (B, W) / (B,): the driven robots
        execute the teacher's actions, with their log-probabilities."""

    def final_values(self, obs: Mapping[str, np.ndarray], rows: np.ndarray) -> np.ndarray:
        """V of the final observations of robots ``rows`` (their truncated episode's last), from their state."""

    def close(self) -> None:
        """Release what the acting holds (nothing here; the server's memory for a ``ServerActing``)."""


def act_on(agent: DynEnvAgent, step: Any, generator: torch.Generator | None, teacher: np.ndarray | None,
           driven: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """Sampled actions (B, W) in the stored dtype and their log-probabilities (B,) from an acting step's heads (the
    teacher's actions and their log-probabilities on the ``driven`` rows)."""
    _, dtype = action_width(agent)
    sampled, log_prob = sample_actions(agent, step, generator)
    actions, log_probs = sampled.numpy().astype(dtype), log_prob.numpy()
    if teacher is not None and driven is not None and driven.any():
        actions[driven] = teacher[driven]
        log_probs[driven] = action_log_prob(agent, step, torch.from_numpy(teacher))[torch.from_numpy(driven)].numpy()
    return actions, log_probs


class LocalActing:
    """Acting in this process: ``agent`` on its device, actions drawn from ``generator``."""

    def __init__(self, agent: DynEnvAgent, generator: torch.Generator | None, batch: int,
                 pose_seeder: Callable[[Tensor], State] | None = None) -> None:
        self.agent, self.generator, self.pose_seeder = agent, generator, pose_seeder
        self.state: State = tuple(s.to(device_of(agent)) for s in agent.initial_state(batch))  # type: ignore

    def seed(self, pose: np.ndarray) -> None:
        if self.pose_seeder is None:
            raise ValueError("privileged pose seeding needs a pose seeder")
        self.state = self.pose_seeder(torch.from_numpy(pose).to(device_of(self.agent)))

    def step(self, obs: Mapping[str, np.ndarray], starts: np.ndarray, last: bool, want_state: bool = False,
             teacher: np.ndarray | None = None, driven: np.ndarray | None = None) -> Acted:
        state = reset_state(self.state, torch.from_numpy(starts))
        start_state = tuple(s.clone() for s in state) if want_state else None
        out = policy_step(self.agent, obs, state)
        acted = Acted(out.value.cpu().numpy(), start_state=start_state)   # type: ignore[arg-type]
        if last:
            return acted
        acted.actions, acted.log_probs = act_on(self.agent, out, self.generator, teacher, driven)
        self.state = out.state
        return acted

    def final_values(self, obs: Mapping[str, np.ndarray], rows: np.ndarray) -> np.ndarray:
        state = tuple(s[torch.from_numpy(rows).to(s.device)] for s in self.state)
        return policy_step(self.agent, obs, state).value.cpu().numpy()   # type: ignore[arg-type, no-any-return]

    def close(self) -> None:
        pass
