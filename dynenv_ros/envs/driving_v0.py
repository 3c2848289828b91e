"""Urban driving through PettingZoo: ``parallel_env(**config)`` (Parallel API), ``env(**config)`` (AEC API,
PettingZoo's standard conversion and wrappers) and ``raw_env(**config)`` (AEC without wrappers).

| | |
|---|---|
| agents | ``car_0`` … ``car_{n-1}`` (n = ``n_cars``, 1–10; the world's ``DrivingWorld.names``) |
| action (``action_mode='discrete'``, default) | MultiDiscrete [acceleration 3, steering 3], the original's: acceleration 0 reverse, 1 **brake**, 2 gas; steering 0 right, 1 straight, 2 left (±0.349 rad/s) |
| action (``action_mode='continuous'``) | Box float32 (3,) [throttle −1..1 (negative: reverse), brake 0..1, steering −0.349..0.349 rad/s yaw rate, + left] |
| observation (``observation='full'``, default) | noise-free ground truth in the car's own frame (x forward, y left), one flat float32 Box: self, other cars, pedestrians, obstacles, lane lines as padded rows with a ``present`` mask (``envs.driving_observations``) |
| reward | sum of the primary, rule, auxiliary and observation terms; each term in ``infos[agent]['reward_terms']`` |
| termination | per car, once it can earn nothing more: crashed, or at its destination with its team's bonus decided (every team-mate finished, or one crashed); such cars leave ``env.agents`` |
| episode | 60 s = 600 periods of 100 ms, then every remaining car is truncated |

Keyword arguments are the settings of ``driving.config.DrivingConfig`` (nested ones as dicts, e.g.
``pedestrians={"count_max": 5}``), plus ``render_mode='rgb_array'``, ``observation`` (a mode of
``driving_observations.OBSERVATION_BUILDERS``), ``perception`` and ``observation_options`` (passed to the
observation mode; ``full`` takes neither) and ``pixels_per_metre`` for rendering.

Actions are checked before anything moves (``DrivingWorld.parse_actions``): a bad one raises ValueError naming the
car and the field. A ``DrivingAction`` or a mapping ``{"throttle", "brake", "steering"}`` is accepted in either mode.
Actions of cars that have left ``env.agents`` are ignored (a wrapper may keep sending them); those cars brake.
A car that reached its destination but waits for its team's bonus stays an agent with its actions ignored, so the
bonus reaches it (the original kept every finished car to the end with zero rewards).

``infos[agent]``: ``reward_terms``, ``events`` (this car's events of the period, as
``"kind"`` or ``"kind: detail"``, e.g. ``"crash: building"``), ``finished``, ``crashed``, ``at_goal`` and whatever
the observation mode adds.
"""
from __future__ import annotations

import math
import warnings
from collections.abc import Mapping
from typing import Any

import numpy as np
from gymnasium import spaces
from pettingzoo import AECEnv, ParallelEnv

from dynenv_ros.driving.cars import ACCELERATION_CHOICES, BRAKE, STEERING_CHOICES
from dynenv_ros.driving.config import DrivingConfig
from dynenv_ros.driving.world import DrivingWorld
from dynenv_ros.envs.aec import raw_aec, wrapped_aec
from dynenv_ros.envs.driving_observations import DrivingGroundTruth, observation_builder
from dynenv_ros.envs.parallel_agents import AgentSpaces, check_step_actions
from dynenv_ros.sim.reward_terms import RewardTerm
from dynenv_ros.sim.seeding import checked_seed

TERMS = tuple(term.name.lower() for term in RewardTerm)


def action_space(config: DrivingConfig) -> spaces.Space:
    """Discrete: MultiDiscrete [3, 3]; continuous: Box [throttle, brake, steering (rad/s)]."""
    if config.action_mode == "discrete":
        return spaces.MultiDiscrete([ACCELERATION_CHOICES, STEERING_CHOICES])
    w = config.cars.max_yaw_rate
    return spaces.Box(np.array([-1.0, 0.0, -w], np.float32), np.array([1.0, 1.0, w], np.float32), dtype=np.float32)


class DrivingParallelEnv(AgentSpaces, ParallelEnv):
    metadata = {"name": "driving_v0", "render_modes": ["rgb_array"], "render_fps": 10, "is_parallelizable": True}

    def __init__(self, render_mode: str | None = None, observation: str = "full", perception: Any = None,
                 observation_options: Mapping[str, Any] | None = None, pixels_per_metre: float = 4.0,
                 **config: Any) -> None:
        if render_mode not in (None, "rgb_array"):
            raise ValueError(f"render_mode must be None or 'rgb_array', got {render_mode!r}")
        if isinstance(pixels_per_metre, bool) or not isinstance(pixels_per_metre, (int, float)) \
                or not math.isfinite(pixels_per_metre) or pixels_per_metre <= 0:
            raise ValueError(f"pixels_per_metre must be a positive number, got {pixels_per_metre!r}")
        self.render_mode = render_mode
        self.pixels_per_metre = float(pixels_per_metre)
        self.config = DrivingConfig.from_mapping(config)
        self.world = DrivingWorld(self.config)
        self.possible_agents = list(self.world.names)
        self.agents: list[str] = []
        self._index = {name: i for i, name in enumerate(self.possible_agents)}
        self.observations = observation_builder(observation, self.config, perception, observation_options)
        self.ground_truth = DrivingGroundTruth(self.config)
        self._action_space = action_space(self.config)
        self._action_spaces = {a: self._action_space for a in self.possible_agents}
        self._observation_spaces = {a: self.observations.space for a in self.possible_agents}
        self.state_space = self.ground_truth.state_space
        self._view = None

    def reset(self, seed: int | None = None, options: dict[str, Any] | None = None):
        """``seed``: None or a whole number in [0, 2^64 - 1] (the world's one generator is re-seeded with it);
        ``options``: None or a mapping. No option is known yet; unknown ones only warn, because PettingZoo's own
        API test passes a dummy one."""
        if options is not None and not isinstance(options, Mapping):
            raise ValueError(f"options must be a mapping or None, got {type(options).__name__}")
        seed = checked_seed(seed)
        if options:
            warnings.warn(f"driving_v0.reset ignores unknown option(s) {sorted(options, key=repr)}", stacklevel=2)
        self.world.reset(seed=seed)
        self.observations.reset(self.world)
        self.agents = self.possible_agents[:]
        observations = self.observations.initial()
        infos = {}
        for i, a in enumerate(self.agents):
            infos[a] = {"reward_terms": dict.fromkeys(TERMS, 0.0), **self._status(i), **self.observations.infos(i)}
        return {a: observations[i] for i, a in enumerate(self.agents)}, infos

    def step(self, actions: dict[str, Any]):
        check_step_actions("driving_v0", self.agents, self._index, actions)
        live = set(self.agents)
        raw = [actions[a] if a in live else BRAKE for a in self.possible_agents]
        result = self.world.step(raw, on_frame=self.observations.on_frame, names=self.possible_agents)
        observations, seen_rewards = self.observations.build()
        result.rewards[RewardTerm.OBSERVATION] += seen_rewards
        totals = result.rewards.sum(axis=0)
        events: dict[int, list[str]] = {}
        for e in result.events:
            text = f"{e.kind}: {e.detail}" if e.detail else e.kind
            # a car's event goes to that car; a team's event (the bonus) to each of its cars
            owners = ([e.robot] if e.robot is not None
                      else [c.index for c in self.world.cars if e.team and c.team == e.team])
            for i in owners:
                events.setdefault(i, []).append(text)
        ended = self.world.cars_done()
        obs, rewards, terminations, truncations, infos = {}, {}, {}, {}, {}
        for agent in self.agents:
            i = self._index[agent]
            obs[agent] = observations[i]
            rewards[agent] = float(totals[i])
            terminations[agent] = result.terminated or ended[i]
            truncations[agent] = result.truncated and not terminations[agent]
            infos[agent] = {"reward_terms": {name: float(result.rewards[t, i]) for t, name in enumerate(TERMS)},
                            "events": events.get(i, []),
                            **self._status(i), **self.observations.infos(i)}
        self.agents = [a for a in self.agents if not (terminations[a] or truncations[a])]
        return obs, rewards, terminations, truncations, infos

    def _status(self, i: int) -> dict[str, bool]:
        car = self.world.cars[i]
        return {"finished": car.finished, "crashed": car.crashed, "at_goal": car.at_goal}

    def state(self) -> np.ndarray:
        """Map-frame ground truth (``driving_observations.DrivingGroundTruth.state``)."""
        return self.ground_truth.state(self.world.snapshot())

    def render(self) -> np.ndarray | None:
        if self.render_mode is None:
            warnings.warn("driving_v0.render() needs render_mode='rgb_array'", stacklevel=2)
            return None
        from dynenv_ros.render.driving import render_driving   # Pillow only when rendering
        from dynenv_ros.render.topdown import as_array
        return as_array(render_driving(self.world.snapshot(), self.world.map, pixels_per_metre=self.pixels_per_metre))

    def close(self) -> None:
        pass


def parallel_env(**config: Any) -> DrivingParallelEnv:
    """The Parallel env: every live car acts at once, as the world steps."""
    return DrivingParallelEnv(**config)


def raw_env(**config: Any) -> AECEnv:
    """The AEC env without wrappers (``envs.aec``): plays exactly the Parallel env's episode, agents in turn."""
    return raw_aec(parallel_env(**config))


def env(**config: Any) -> AECEnv:
    """The AEC env as PettingZoo's docs use it: ``raw_env`` under ``OrderEnforcingWrapper`` (``envs.aec``)."""
    return wrapped_aec(parallel_env(**config))


__all__ = ["DrivingParallelEnv", "parallel_env", "env", "raw_env", "action_space", "TERMS"]
