"""RoboCup SPL soccer through PettingZoo: ``parallel_env(**config)`` (Parallel API), ``env(**config)`` (AEC API,
PettingZoo's standard conversion and wrappers) and ``raw_env(**config)`` (AEC without wrappers).

| | |
|---|---|
| agents | ``team_a_0`` … ``team_a_{n-1}``, ``team_b_0`` … (n = ``players_per_team``, 1–5) |
| action (``head_mode='discrete'``) | MultiDiscrete [walk 5, turn 3, kick 3, head 7]: see ``soccer.actions`` |
| action (``head_mode='continuous'``) | Dict ``motion`` MultiDiscrete [5, 3, 3], ``head`` Box rad per period |
| observation (``observation='partial'``) | per vision frame, the robot's detections as float32 rows (variable length), proprioception and the GameController's ``game`` state (``envs.soccer_observations``) |
| observation (``'padded'``) | the same as fixed-shape Box arrays with masks and the previous action (``envs.padded_layout``): what Stable-Baselines3, SuperSuit, RLlib batch |
| observation (``'full'`` / ``'image'``) | team-frame ground truth / top and bottom camera segmentation per frame (uint8 0/255 image, channels first) |
| perception | ``perception='realistic'`` (default), ``'dynenv'``, ``'none'``, or ``{"preset": …, "noise_magnitude": …, "mode": …}`` |
| localization | ``localization='none'`` (default, the paper's) or ``'estimate'``: the emulated self-localization runs and every observation (partial, padded, image) gains ``pose_estimate`` (7,) float32, the team-frame pose estimate (``envs.pose_features``) |
| reward | sum of the primary, rule, auxiliary and observation terms; each term in ``infos[agent]['reward_terms']`` |
| episode | 120 s = 240 motion periods, then every agent is truncated |

Keyword arguments are the settings of ``soccer.config.SoccerConfig`` (nested ones as dicts), plus
``render_mode='rgb_array'``, ``observation``, ``perception``, ``localization``, ``image_size=(width, height)`` and,
for the padded layout, ``max_landmarks`` / ``max_objects`` (rows per frame; the farthest beyond them are dropped and
counted in ``infos[agent]['dropped_detections']``).

Head modes for learners: ``head_mode='discrete'`` (default) makes the whole action one ``MultiDiscrete``, which every
PPO implementation accepts (Stable-Baselines3, CleanRL, RLlib). ``head_mode='continuous'`` gives a ``Dict`` of a
``MultiDiscrete`` and a ``Box`` (a hybrid action), which this project's agent handles with a Gaussian head but which
Stable-Baselines3's PPO does not accept; use the discrete head with such libraries.
"""
from __future__ import annotations

import warnings
from collections.abc import Mapping
from typing import Any

import numpy as np
from pettingzoo import AECEnv, ParallelEnv

from dynenv_ros.envs.aec import raw_aec, wrapped_aec
from dynenv_ros.envs.soccer_observations import LOCALIZATION_OPTIONS, SoccerObservations
from dynenv_ros.envs.soccer_session import kickoff_team
from dynenv_ros.envs.soccer_spaces import GroundTruthEncoder, action_space
from dynenv_ros.envs.parallel_agents import AgentSpaces, check_step_actions
from dynenv_ros.sim.reward_terms import RewardTerm
from dynenv_ros.sim.seeding import checked_seed
from dynenv_ros.soccer.config import SoccerConfig
from dynenv_ros.soccer.world import SoccerWorld

RESET_OPTIONS = ("kickoff_team",)
_TERM_NAMES = tuple(term.name.lower() for term in sorted(RewardTerm))   # rows of a period's rewards


class RoboCupParallelEnv(AgentSpaces, ParallelEnv):
    metadata = {"name": "robocup_v0", "render_modes": ["rgb_array"], "render_fps": 2, "is_parallelizable": True}

    def __init__(self, render_mode: str | None = None, observation: str = "partial",
                 perception: Any = "realistic", image_size: tuple[int, int] = (640, 480),
                 max_landmarks: int | None = None, max_objects: int | None = None, localization: str = "none",
                 **config: Any) -> None:
        if render_mode not in (None, "rgb_array"):
            raise ValueError(f"render_mode must be None or 'rgb_array', got {render_mode!r}")
        self.render_mode = render_mode
        self.config = SoccerConfig.from_mapping(config)
        self.world = SoccerWorld(self.config)
        self.possible_agents = self.config.robot_names
        self.agents: list[str] = []
        self._index = {name: i for i, name in enumerate(self.possible_agents)}
        self.encoder = GroundTruthEncoder(self.config)
        if localization not in LOCALIZATION_OPTIONS:       # a bool is SoccerObservations' own, not a setting
            raise ValueError(f"localization must be one of {LOCALIZATION_OPTIONS}, got {localization!r}")
        self.observations = SoccerObservations(self.config, observation, perception, image_size, max_landmarks,
                                               max_objects, localization)
        self._action_space = action_space(self.config)
        self._action_spaces = {a: self._action_space for a in self.possible_agents}
        self._observation_spaces = {a: self.observations.space for a in self.possible_agents}
        self.state_space = self.encoder.state_space

    def reset(self, seed: int | None = None, options: dict[str, Any] | None = None):
        """``seed``: None or a whole number in [0, 2^64 - 1]; ``options``: None or a mapping, ``kickoff_team`` 'a' or
        'b'. Ill-typed values raise ValueError with the reason; unknown options only warn, because PettingZoo's own
        API test passes a dummy one."""
        if options is not None and not isinstance(options, Mapping):
            raise ValueError(f"options must be a mapping (e.g. {{'kickoff_team': 'b'}}) or None, "
                             f"got {type(options).__name__}")
        options = dict(options or {})
        seed = checked_seed(seed)
        unknown = sorted(set(options) - set(RESET_OPTIONS), key=repr)
        if unknown:
            warnings.warn(f"robocup_v0.reset ignores unknown option(s) {unknown}; known: {list(RESET_OPTIONS)}",
                          stacklevel=2)
        try:
            kickoff = kickoff_team(options.get("kickoff_team", "a"))
        except ValueError as error:
            raise ValueError(f"options['kickoff_team']: {error}") from None
        self.world.reset(seed=seed, kickoff_team=kickoff)
        self.observations.reset(self.world)
        self.agents = self.possible_agents[:]
        observations = self.observations.initial()
        zero_terms = {term.name.lower(): 0.0 for term in RewardTerm}
        return ({a: observations[i] for i, a in enumerate(self.agents)},
                {a: {"reward_terms": dict(zero_terms)} for a in self.agents})

    def step(self, actions: dict[str, Any]):
        check_step_actions("robocup_v0", self.agents, self._index, actions)
        result = self.world.step([actions[a] for a in self.possible_agents], on_frame=self.observations.on_frame,
                                 names=self.possible_agents)
        observations, seen_rewards = self.observations.build()
        result.rewards[RewardTerm.OBSERVATION] += seen_rewards
        totals = result.rewards.sum(axis=0).tolist()
        # Rows of the rewards are the terms in RewardTerm order; one conversion to Python floats for all.
        terms = [dict(zip(_TERM_NAMES, column)) for column in result.rewards.T.tolist()]
        obs, rewards, terminations, truncations, infos = {}, {}, {}, {}, {}
        for i, agent in enumerate(self.agents):
            obs[agent] = observations[i]
            rewards[agent] = totals[i]
            terminations[agent] = result.terminated
            truncations[agent] = result.truncated
            infos[agent] = {"reward_terms": terms[i]}
            if self.observations.mode == "padded":
                infos[agent]["dropped_detections"] = int(self.observations.dropped_rows[i])
        if result.terminated or result.truncated:
            self.agents = []
        return obs, rewards, terminations, truncations, infos

    def state(self) -> np.ndarray:
        return self.encoder.state(self.world)

    def render(self) -> np.ndarray | None:
        if self.render_mode is None:
            warnings.warn("robocup_v0.render() needs render_mode='rgb_array'", stacklevel=2)
            return None
        from dynenv_ros.render.topdown import as_array, render_snapshot   # Pillow only when rendering
        return as_array(render_snapshot(self.world.snapshot(), self.config.field,
                                        ball_radius=self.config.ball.radius))

    def close(self) -> None:
        pass


def parallel_env(**config: Any) -> RoboCupParallelEnv:
    """The Parallel env: every robot acts at once, as the world steps."""
    return RoboCupParallelEnv(**config)


def raw_env(**config: Any) -> AECEnv:
    """The AEC env without wrappers (``envs.aec``): plays exactly the Parallel env's episode, agents in turn."""
    return raw_aec(parallel_env(**config))


def env(**config: Any) -> AECEnv:
    """The AEC env as PettingZoo's docs use it: ``raw_env`` under ``OrderEnforcingWrapper`` (``envs.aec``)."""
    return wrapped_aec(parallel_env(**config))


__all__ = ["RoboCupParallelEnv", "parallel_env", "env", "raw_env"]
