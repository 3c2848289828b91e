"""Who the learner plays against: itself (one shared network for both teams — every robot's experience trains it),
frozen snapshots of itself, or uniformly random actions. Observations are in each robot's own team frame, so one
network plays either side unchanged."""
from __future__ import annotations

import copy
from typing import Mapping

import numpy as np
import torch

from dynenv_ros.agent.network import DynEnvAgent
from dynenv_ros.learning.sampling.collector import Opponent
from dynenv_ros.learning.algo.policy import policy_step, reset_state, sample_actions
from dynenv_ros.soccer.scripted import DEFAULT_SCRIPTED

SCRIPTED_TEAM = DEFAULT_SCRIPTED      # what "scripted" means, here as in dynenv-eval


class WorldScriptedOpponent(Opponent):
    """Team B played inside the worlds (``SoccerVectorEnv(scripted_team_b=...)``: the ground-truth scripted team,
    or the perceiving one on its robots' own observations): its rows are ignored there."""

    def act(self, obs: Mapping[str, np.ndarray], starts: np.ndarray) -> np.ndarray:
        return np.zeros((*starts.shape, 4), np.int64)


class RandomOpponent(Opponent):
    """Uniform over every action head (walk 5, turn 3, kick 3, head 2·units+1), from its own generator."""

    def __init__(self, rng: np.random.Generator, head_choices: int = 7) -> None:
        self.rng = rng
        self.sizes = np.array([5, 3, 3, head_choices])

    def act(self, obs: Mapping[str, np.ndarray], starts: np.ndarray) -> np.ndarray:
        return self.rng.integers(0, self.sizes, size=(*starts.shape, 4))


class SnapshotOpponent(Opponent):
    """A pool of frozen copies of the learner; ``refresh`` adds the current weights (dropping the oldest beyond
    ``pool`` entries) and each refresh picks the pool member that plays next, at random. Acts stochastically,
    with its own recurrent state per robot."""

    def __init__(self, agent: DynEnvAgent, pool: int, generator: torch.Generator, rng: np.random.Generator) -> None:
        self.pool_size = pool
        self.generator, self.rng = generator, rng
        self.pool: list[DynEnvAgent] = []
        self.playing: DynEnvAgent | None = None
        self.state: tuple[torch.Tensor, ...] | None = None
        self.refresh(agent)

    def refresh(self, agent: DynEnvAgent) -> None:
        frozen = copy.deepcopy(agent).eval()
        for p in frozen.parameters():
            p.requires_grad_(False)
        self.pool = (self.pool + [frozen])[-self.pool_size:]
        self.playing = self.pool[int(self.rng.integers(len(self.pool)))]

    def load_pool(self, states: list[Mapping[str, np.ndarray]]) -> None:
        """The pool as a resumed run's checkpoint had it (``run.snapshot_history``: oldest first), replacing what
        ``__init__`` took; the member that plays is drawn again."""
        if not states:
            return
        template = self.pool[-1]
        pool = []
        for state in states[-self.pool_size:]:
            frozen = copy.deepcopy(template)
            frozen.load_state_dict({name: torch.as_tensor(value) for name, value in state.items()})
            pool.append(frozen)
        self.pool, self.state = pool, None
        self.playing = self.pool[int(self.rng.integers(len(self.pool)))]

    @torch.no_grad()
    def act(self, obs: Mapping[str, np.ndarray], starts: np.ndarray) -> np.ndarray:
        E, k = starts.shape
        flat = {key: v.reshape(E * k, *v.shape[2:]) for key, v in obs.items()}
        if self.state is None or self.state[0].shape[0] != E * k:
            device = next(self.playing.parameters()).device
            self.state = tuple(s.to(device) for s in self.playing.initial_state(E * k))
        state = reset_state(self.state, torch.from_numpy(starts.reshape(-1)))
        step = policy_step(self.playing, flat, state)
        actions, _ = sample_actions(self.playing, step, self.generator)
        self.state = step.state
        return actions.numpy().astype(np.int64).reshape(E, k, 4)
