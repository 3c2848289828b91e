"""The worlds a training run learns in: its vector env, which robots learn, who plays the others, and the collector
that steps them with the policy — built the same way for the in-process trainer (all ``num_envs`` worlds) and for
each rollout worker of the asynchronous runner (its share of them).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable

import numpy as np
import torch

from dynenv_ros.envs.vector import DrivingVectorEnv, SoccerVectorEnv
from dynenv_ros.learning.config import TrainConfig
from dynenv_ros.learning.algo.networks import TrainingNetworks
from dynenv_ros.learning.sampling.opponents import (SCRIPTED_TEAM, RandomOpponent, SnapshotOpponent,
                                                    WorldScriptedOpponent)
from dynenv_ros.learning.sampling.collector import ActingFactory, RolloutCollector
from dynenv_ros.scenarios import DRIVING, SOCCER
from dynenv_ros.soccer.config import SoccerConfig

# DynEnv's privileged seeding noise: N(0, 0.05²) in its normalised units (1 unit = 5.2 m) on x, y; 0.05 on the
# unit-vector components of the pose (docs/original.md §9.6).
SEED_NOISE = np.array([0.26, 0.26, 0.05, 0.05, 0.05, 0.05], np.float32)


def soccer_config(cfg: TrainConfig, stage: int | None = None) -> SoccerConfig:
    """The worlds' settings: the run's, with curriculum stage ``stage``'s start and episode length (None: the plain
    kickoff game, the settings without a curriculum)."""
    settings: dict[str, Any] = {"players_per_team": cfg.players_per_team, "head_mode": cfg.head_mode}
    if cfg.episode_seconds is not None:
        settings["episode_seconds"] = cfg.episode_seconds
    if stage is not None and cfg.curriculum:
        settings.update(cfg.curriculum[stage].soccer_settings())
    return SoccerConfig.from_mapping(settings)


def reward_transform(cfg: TrainConfig) -> Callable[[np.ndarray], np.ndarray] | None:
    """The reward learnt from the (…, 4) terms: their weighted sum; None for the plain total (all weights 1)."""
    if cfg.reward_weights == (1.0, 1.0, 1.0, 1.0):
        return None
    weights = np.asarray(cfg.reward_weights, np.float32)
    return lambda terms: (terms * weights).sum(-1)


def needs_targets(cfg: TrainConfig) -> bool:
    """The worlds must write the self-supervised targets (true pose, objects): a loss or the seeding reads them."""
    losses = cfg.losses()
    return losses.localization or losses.reconstruction or cfg.privileged_pose_seeding


def padded_objects(cfg: TrainConfig) -> int | None:
    """The object slots every world pads to when a run mixes team sizes (``team_sizes``): the largest size's, so
    every rollout has one layout; None otherwise (each world's own)."""
    if not cfg.team_sizes:
        return None
    from dynenv_ros.envs.padded_layout import PaddedLayout
    return PaddedLayout.for_players(max(cfg.team_sizes), 1).max_objects


def make_env(cfg: TrainConfig, num_envs: int, backend: str, stage: int = 0) -> tuple[Any, np.ndarray]:
    """The vector env of ``cfg``'s scenario (padded observations) and the robots (cars) of each world that learn;
    soccer's worlds start in curriculum stage ``stage`` (``follow_curriculum`` moves them on)."""
    return _VECTOR_ENVS[cfg.world.name](cfg, num_envs, backend, stage)


def _driving_env(cfg: TrainConfig, num_envs: int, backend: str, stage: int) -> tuple[Any, np.ndarray]:
    driving: dict[str, Any] = {"n_cars": cfg.n_cars, "action_mode": cfg.action_mode}
    if cfg.episode_seconds is not None:
        driving["episode_seconds"] = cfg.episode_seconds
    env = DrivingVectorEnv(num_envs, backend=backend, observation="padded", config=driving,
                           perception=cfg.perception, teacher=cfg.teacher)
    return env, np.arange(cfg.n_cars)


def _soccer_env(cfg: TrainConfig, num_envs: int, backend: str, stage: int) -> tuple[Any, np.ndarray]:
    env = SoccerVectorEnv(num_envs, backend=backend, config=soccer_config(cfg, stage if cfg.curriculum else None),
                          observation="padded",
                          perception=cfg.perception, targets=needs_targets(cfg),
                          scripted_team_b=IN_WORLD_TEAMS.get(cfg.opponent), teacher=cfg.teacher,
                          localization=cfg.localization, max_objects=padded_objects(cfg),
                          league_members=cfg.league_members if cfg.opponent == "league" else None)
    n = cfg.players_per_team
    return env, (np.arange(2 * n) if cfg.opponent == "self" else np.arange(n))


# Each scenario's vector env, by its name: the registry sits below learning/ and cannot build them (docs/decisions.md,
# "A scenario registry").
_VECTOR_ENVS: dict[str, Callable[[TrainConfig, int, str, int], tuple[Any, np.ndarray]]] = {
    SOCCER.name: _soccer_env, DRIVING.name: _driving_env}


# opponents the worlds play themselves (team B's rows of the learner's actions are ignored)
IN_WORLD_TEAMS = {"scripted": SCRIPTED_TEAM, "perceiving": "perceiving", "league": "league"}


@dataclass
class Worlds:
    env: Any                     # SoccerVectorEnv or DrivingVectorEnv, padded observations
    learning_robots: np.ndarray  # robot (car) indices of each world that the learner controls
    opponent: Any                # who plays the other robots (None: nobody else)
    collector: RolloutCollector
    stage: int = 0               # the curriculum stage the worlds' next episodes start in (follow_curriculum)


def follow_curriculum(worlds: Worlds, cfg: TrainConfig, env_steps: int) -> int:
    """Move the worlds to the curriculum stage of the learner's ``env_steps`` once it differs from theirs: each world
    changes at its next episode boundary, the episodes under way finish as they began. Returns the stage."""
    stage = cfg.curriculum_stage(env_steps)
    if stage != worlds.stage:
        worlds.env.configure(soccer_config(cfg, stage))
        worlds.stage = stage
    return stage


def make_worlds(cfg: TrainConfig, networks: TrainingNetworks, num_envs: int, backend: str, generator: torch.Generator,
                rng: np.random.Generator, seed: int, acting: ActingFactory | None = None, env_steps: int = 0) -> Worlds:
    """``num_envs`` worlds of ``cfg``'s scenario stepped by ``networks.agent`` (``backend``: the vector env's), the
    opponent the config names and the collector; ``generator`` samples actions (and a snapshot opponent's), ``rng``
    draws random opponents and seeding noise, ``seed`` seeds the worlds; ``acting``: how the learning robots act
    (default: here, with ``networks``; a rollout worker of ``inference: server`` passes the server's); ``env_steps``:
    the learner's count, whose curriculum stage the first episodes start in (a resumed run's)."""
    agent = networks.agent
    stage = cfg.curriculum_stage(env_steps)
    env, learning = make_env(cfg, num_envs, backend, stage)
    if cfg.world.layout_follows_settings:
        agent.layout_spec = env.layout.spec
    opponent: Any = None
    if cfg.opponent == "random":
        opponent = RandomOpponent(rng, 2 * soccer_config(cfg).motion.head_units + 1)
    elif cfg.opponent in ("snapshot", "league"):      # the league's snapshot member acts through the collector
        opponent = SnapshotOpponent(agent, cfg.snapshot_pool, generator, rng)
    elif cfg.opponent in IN_WORLD_TEAMS:             # (team B's rows ignored where the worlds play it)
        opponent = WorldScriptedOpponent()
    seeding: dict[str, Any] = {}
    if cfg.privileged_pose_seeding:
        seeding = {"pose_seeder": networks.seeded_state, "seed_noise": SEED_NOISE, "rng": rng}
    try:
        collector = RolloutCollector(env, agent, learning, opponent, generator, seed=seed,
                                     reward_transform=reward_transform(cfg), acting=acting, **seeding)
    except BaseException:
        env.close()
        raise
    return Worlds(env, learning, opponent, collector, stage)


def teacher_driven_share(cfg: TrainConfig, env_steps: int, first_world: int, num_envs: int) -> int:
    """How many of the worlds ``first_world .. first_world + num_envs - 1`` (of the run's ``num_envs``) execute the
    teacher's actions after ``env_steps``: the run's first ``teacher_driven_worlds`` worlds until
    ``teacher_driven_env_steps`` (0 = for ever)."""
    done = cfg.teacher_driven_env_steps and env_steps >= cfg.teacher_driven_env_steps
    driven = 0 if done else cfg.teacher_driven_worlds
    return int(np.clip(driven - first_world, 0, num_envs))
