"""What the algorithm learns from: a rollout's arrays and their tensors (``Rollout``), one update's experience
(``Experience``), and where experience comes from (``ExperienceSource``, the training loop's one input: ``loop``).

One rollout is T motion periods of every world. Stored per step t and learning robot b (robots flattened world
by world, ``(E, A_learning) -> B``):

- ``obs[key]`` (T+1, B, ...): the padded observation layout (``envs.padded_layout``), observation t being what
  the policy acted on at step t; observation T is the one after the last step (the next rollout's first).
- ``actions`` (T, B, 4) int64, ``log_probs`` and ``values`` (T, B) of the behaviour policy at acting time (PPO's
  ratio is taken against these, never against resampled actions — DynEnv's PPO bug, docs/original.md §12.13).
- ``rewards`` (T, B) and ``reward_terms`` (T, B, 4); ``episode_end``, ``truncated`` (T, B); ``final_values``
  (T, B): the critic at the finished episode's final observation (truncation bootstrap).
- ``starts`` (T+1, B): observation t is an episode's first (the recurrent state is zeroed before it).
- ``can_act`` (T+1, B): the robot was neither fallen nor penalized, so its action had an effect.
- ``targets`` (T+1, B, ...): the self-supervised targets of observation t (``SoccerVectorEnv(targets=True)``),
  with ``ball_known`` / ``robots_known``: seen at least once since the episode began (DynEnv wiped this memory
  every 6-step rollout, §12.18; here it lasts the episode).
- ``initial_state``: the recurrent state before step 0, so the learner re-runs whole sequences from it.
- ``teacher_actions`` (T, B, width) (a vector env made with ``teacher=...`` only): the scripted teacher's action in
  the state of observation t (``envs.teacher``), the imitation loss's label, in the dtype and units of ``actions``
  (soccer (T, B, 4) int64; driving its action mode's); the learner's own action is executed (except in
  teacher-driven worlds, soccer only).
- ``teacher_driven`` (B,) bool: the robot executed the teacher's actions in this rollout (DAgger's β share of the
  worlds, ``drive_with_teacher``); its steps are off-policy, so the learner leaves them out of the policy, entropy
  and value terms and learns from them only by imitation and the auxiliary losses.

Driving (``DrivingVectorEnv``, ``agent.scenario == 'driving'``): every car of every world learns; ``actions`` are
(T, B, 2) int64 [acceleration, steering] or (T, B, 3) float32 normalised [throttle, brake, steering / limit] (the
env gets the steering times its limit), ``reward_terms`` keep the env's four terms. Per-car termination
(``BatchStep.agents_terminated``): a car's episode ends at the step it crashed or got home with its team's bonus
decided — ``episode_end`` True, ``truncated`` False there (terminated: no bootstrap); the steps after it, until its
world's episode ends, are *dead*: ``alive`` (T+1, B) False, ``can_act`` False, reward 0, ``episode_end`` True (so no
return flows across them) — the learner takes no sample of any kind from them (policy, value, entropy, curiosity).
A car still driving when its world hits the time limit ends truncated (bootstrapped from its final observation). The
recurrent state restarts with the world's next episode. Finished episodes are reported per car with ``home`` and
``crashed``.

Everything is numpy until ``as_tensors``; nothing per detection is ever a Python object.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Mapping, Protocol

import numpy as np
import torch
from torch import Tensor

from dynenv_ros.agent.network import State


@dataclass(eq=False)      # identity: arrays have no truth value (a queue's remove compares its elements)
class StepArrays:
    """The arrays every learner input has, per step (see the module docstring): a rollout of the vectorised batch
    (robot axis B) or one robot's sequence assembled from messages (``messages.assembly``, no robot axis)."""
    obs: dict[str, np.ndarray]
    actions: np.ndarray
    log_probs: np.ndarray
    values: np.ndarray
    rewards: np.ndarray
    reward_terms: np.ndarray
    episode_end: np.ndarray
    truncated: np.ndarray
    final_values: np.ndarray
    starts: np.ndarray
    can_act: np.ndarray


@dataclass(eq=False)
class Rollout(StepArrays):
    """One rollout's arrays (see the module docstring); ``robots_per_world`` learning robots in each world."""
    initial_state: State
    targets: dict[str, np.ndarray] = field(default_factory=dict)
    seed_pose: np.ndarray | None = None     # (B, 6) privileged seeding only: the noisy true pose at step 0
    teacher_actions: np.ndarray | None = None   # (T, B, width) teacher labels (a vector env's teacher=...) or None
    teacher_driven: np.ndarray | None = None    # (B,) bool: executed the teacher's actions (off-policy rows)
    alive: np.ndarray | None = None             # (T+1, B) bool, driving: the car's episode had not ended yet

    @property
    def steps(self) -> int:
        return int(self.actions.shape[0])

    @property
    def robots(self) -> int:
        return int(self.actions.shape[1])

    def as_tensors(self, device: torch.device | str = "cpu") -> dict[str, Any]:
        """Every array as a tensor on ``device`` (observation and target dicts stay dicts)."""
        extra = {}
        if self.seed_pose is not None:
            extra["seed_pose"] = self.seed_pose
        if self.teacher_actions is not None:
            extra["teacher_actions"] = self.teacher_actions
        if self.teacher_driven is not None and self.teacher_driven.any():
            extra["teacher_driven"] = self.teacher_driven
        if self.alive is not None:
            extra["alive"] = self.alive
        arrays = {name: getattr(self, name) for name in STEP_ARRAYS}
        return arrays_as_tensors({**arrays, **extra, "obs": self.obs, "targets": self.targets},
                                 self.initial_state, device)


# The per-step arrays of a rollout (see the module docstring), in the form ``ppo.update`` takes.
STEP_ARRAYS = ("actions", "log_probs", "values", "rewards", "reward_terms", "episode_end", "truncated",
               "final_values", "starts", "can_act")


def arrays_as_tensors(arrays: Mapping[str, Any], initial_state: State, device: torch.device | str = "cpu"
                      ) -> dict[str, Any]:
    """A rollout's numpy arrays (``STEP_ARRAYS``, ``obs`` and ``targets`` dicts, optional extras such as
    ``teacher_actions``) → the tensors ``ppo.update`` takes, with ``initial_state``."""
    def tensor(x: np.ndarray) -> Tensor:
        return torch.from_numpy(np.ascontiguousarray(x)).to(device)
    out: dict[str, Any] = {key: (tensor(value) if not isinstance(value, Mapping)
                                 else {k: tensor(v) for k, v in value.items()}) for key, value in arrays.items()}
    out["initial_state"] = tuple(s.to(device) for s in initial_state)
    return out


@dataclass
class Experience:
    """What one update learns from: ``batch``, the tensors ``ppo.update`` takes (a rollout's, several workers' rollouts
    joined, or message sequences batched), the env steps in it, the episodes that finished while it was gathered, and
    scalars to log about it (averaged over a log window, or the maximum for ``*_max``)."""
    batch: Mapping[str, Any]
    env_steps: int
    finished: list[dict[str, float]] = field(default_factory=list)
    scalars: dict[str, float] = field(default_factory=dict)


@dataclass
class Progress:
    """How far a run has come: env steps learnt from, updates made, episodes finished (what its checkpoints keep)."""
    env_steps: int = 0
    updates: int = 0
    episodes: int = 0


class ExperienceSource(Protocol):
    """Where a run's experience comes from: this process's worlds (``sampling.in_process``), rollout workers
    (``distributed.pool_source``: processes or Ray actors), the trainer node's messages and recorded bags
    (``messages``). The loop pulls from it, so a source decides how long it waits and what it drops."""

    def next(self, progress: Progress, deadline: float) -> Experience | None:
        """The next experience to learn from; None when none came before ``deadline`` (``time.perf_counter``'s
        clock) or the source has nothing more to give."""
        ...

    def learned(self, progress: Progress) -> None:
        """The update on the last experience is made and counted in ``progress``: hand out the new weights, give
        back what the experience held."""
        ...

    def close(self) -> None:
        """Stop whatever the source runs (worlds, workers); a second call does nothing."""
        ...
