"""Many independent worlds stepped together, as arrays: in this process or in worker processes.

``SoccerVectorEnv(E, observation="padded")`` (the default) returns what every robot perceives — the emulated vision
pipeline's detections, with its misses, confusions and errors — in the fixed-shape layout of
``envs.padded_layout``: a dict of float32 arrays with leading (E, A) axes, exactly ``PaddedLayout.empty(E, A)``'s
keys and shapes (``env.layout``), the same arrays ``robocup_v0.parallel_env(observation="padded")`` gives a world
with the same seed. Rewards include the observation term (what was truly seen). ``observation="full"`` gives the
noise-free ground truth (E, A, D) instead, without perception.

Each world writes its rows straight into its slice of the batch's arrays (``SoccerObservations.build_padded``). The
subprocess backend splits the worlds into shards, one per core: this process steps the first shard itself
(``parent_steps=True``, the default) while a worker process steps each of the others, so no core sleeps through the
step. The arrays live in shared memory — one block per key, created by this process, each shard writing its worlds'
slice in place, the actions in a block of their own — so a step's pipe traffic is one short message each way per
worker, never a detection; the blocks are unlinked on ``close()``, when the env is garbage-collected, and if
start-up fails.

Both backends give bit-identical results for the same seed: each world has its own generator, seeded from one
``SeedSequence`` (``_seeds``), and actions are validated in this process before any world moves. Which backend is
faster depends on the machine: see docs/benchmarks.md (`dynenv-bench vector`). Finished episodes reset
automatically; the last observation of a finished episode is returned separately in ``final_observations``.
``targets=True`` adds the self-supervised localization and reconstruction targets of every robot
(``envs.learning_targets``), written by the worlds into the batch's arrays like the observations.

``DrivingVectorEnv`` is the same batch over driving worlds (``driving_v0``'s perception and its padded layout, with
(E, A) axes over cars): the batch machinery (``InProcessBatch``, ``SubprocessBatch``, ``VectorEnv``) reads what is
scenario-specific from the settings (``_Settings`` soccer, ``_DrivingSettings`` driving): the world, the observation
builder, the action width and checks, and the batch that steps the worlds in one process (``InProcessBatch``
soccer's, ``DrivingInProcessBatch`` driving's: its own arrays, first observations, reset and step).
"""
from __future__ import annotations

import multiprocessing as mp
import os
import pickle
import weakref
from dataclasses import dataclass, field, replace
from functools import partial
from multiprocessing import shared_memory
from multiprocessing.connection import Connection
from typing import Any, Callable, Mapping, Sequence, Union

import numpy as np

from dynenv_ros.core.shared_arrays import SharedArrays
from dynenv_ros.driving.config import DrivingConfig
from dynenv_ros.envs.league import LEAGUE_MEMBERS, League
from dynenv_ros.envs.learning_targets import target_shapes
from dynenv_ros.envs.padded_layout import PaddedLayout
from dynenv_ros.envs.soccer_observations import LOCALIZATION_OPTIONS, SoccerObservations, perception_params
from dynenv_ros.envs.teacher import (DRIVING_TEACHERS, PERCEIVED_KEYS, PERCEIVING_TEACHER, TEACHERS, DrivingTeacher,
                                     PerceivingTeacher, Teacher, make_soccer_teacher)
from dynenv_ros.perception.params import PerceptionParams
from dynenv_ros.sim.reward_terms import RewardTerm
from dynenv_ros.soccer.actions import Kick, Turn, Walk, parse_action
from dynenv_ros.soccer.config import SoccerConfig
from dynenv_ros.soccer.perceiving import perceiving_team
from dynenv_ros.soccer.scripted import team_policies
from dynenv_ros.soccer.world import SoccerWorld

# backend="auto": worker processes from this many worlds on (measured on 2 cores, docs/benchmarks.md): a world with
# perception costs ~4x one with ground truth only, so workers pay for their pipe round trips much sooner.
AUTO_SUBPROCESS_MIN_ENVS = {"padded": 2, "full": 8}
VECTOR_OBSERVATIONS = ("padded", "full")
FULL_KEY = "observation"        # the storage key of ground-truth observations
N_TERMS = len(RewardTerm)

Observation = Union[dict[str, np.ndarray], np.ndarray]


@dataclass
class BatchStep:
    observations: Observation      # padded: {key: (E, A, ...)}; full: (E, A, D) float32 — after any automatic reset
    rewards: np.ndarray            # (E, A) float64, the sum of the terms
    reward_terms: np.ndarray       # (E, T, A) float64, T = RewardTerm (observation term included in padded mode)
    terminated: np.ndarray         # (E,) bool
    truncated: np.ndarray          # (E,) bool
    final_observations: dict[int, Observation]   # env index -> last observation of its finished episode, (A, ...)
    dropped_detections: np.ndarray  # (E, A) int64: detection rows beyond the layout's maxima (padded; else 0)
    # targets=True: the learning targets of the same instant as ``observations`` (envs.learning_targets), as
    # {key: (E, A, ...)} float32, and those of each finished episode's last observation; else None and {}.
    targets: dict[str, np.ndarray] | None = None
    final_targets: dict[int, dict[str, np.ndarray]] = field(default_factory=dict)
    # teacher=KIND: (E, A, width), the scripted teacher's action for each robot or car at ``observations``' instant
    # (envs.teacher): soccer (E, A, 4) int64; driving (E, A, 2) int64 or, continuous, (E, A, 3) float32; else None.
    teacher_actions: np.ndarray | None = None
    # Driving: (E, A) bool, the car can earn nothing more this episode (driving_v0's per-car termination: crashed, or
    # home with its team's bonus decided; every car when the episode ended by itself); else None.
    agents_terminated: np.ndarray | None = None


def _seeds(seed: int | None, count: int) -> list[int]:
    children = np.random.SeedSequence(seed).spawn(count)
    return [int(child.generate_state(1, np.uint64)[0]) for child in children]


LEAGUE = "league"           # team B drawn per world and episode from the league's members (envs.league)
SCRIPTED_TEAMS_B = (None, "chaser", "keeper_and_chasers", PERCEIVING_TEACHER, LEAGUE)


@dataclass(frozen=True)
class _Settings:
    """What every world of a batch is built from (pickled once to each worker)."""
    config: SoccerConfig
    observation: str
    perception: PerceptionParams
    max_landmarks: int | None
    max_objects: int | None
    targets: bool = False
    scripted_team_b: str | None = None
    teacher: str | None = None
    localization: str = "none"   # "estimate": the observations gain pose_estimate (envs.pose_features)
    league_members: tuple[str, ...] = LEAGUE_MEMBERS     # scripted_team_b="league": whom the league draws from
    scenario = "soccer"
    action_width = 4             # [walk, turn, kick, head]
    teacher_dtype = np.dtype(np.int64)

    def make_teacher(self) -> Teacher | PerceivingTeacher | None:
        return make_soccer_teacher(self.config, self.teacher) if self.teacher is not None else None

    @property
    def n_agents(self) -> int:
        return self.config.n_robots

    def observations(self) -> SoccerObservations:
        # the perceiving teacher reads the pose estimate: the localization runs for it, observed or not
        localization: bool | str = self.localization
        if (PERCEIVING_TEACHER in (self.teacher, self.scripted_team_b) or self.scripted_team_b == LEAGUE) \
                and localization == "none":
            localization = True     # the perceiving opponent reads it too
        return SoccerObservations(self.config, self.observation, self.perception,
                                  max_landmarks=self.max_landmarks, max_objects=self.max_objects,
                                  localization=localization)

    def make_world(self) -> SoccerWorld:
        return SoccerWorld(self.config)

    def full_observations(self, observations: SoccerObservations, world: SoccerWorld) -> np.ndarray:
        return observations.ground_truth.observations(world)

    def validate_actions(self, actions: Any, num_envs: int) -> Any:
        return validate_actions(actions, self.config, num_envs)

    @property
    def batch_type(self) -> type[InProcessBatch]:
        """What steps these worlds in one process."""
        return InProcessBatch


@dataclass(frozen=True)
class _DrivingSettings:
    """What every driving world of a batch is built from (pickled once to each worker)."""
    config: DrivingConfig
    observation: str
    perception: Any                      # DrivingPerceptionParams (padded) or None (full)
    max_lanes: int | None
    max_objects: int | None
    teacher: str | None = None
    targets = False
    scripted_team_b = None
    scenario = "driving"

    @property
    def n_agents(self) -> int:
        return self.config.n_cars

    @property
    def action_width(self) -> int:       # discrete [acceleration, steering]; continuous [throttle, brake, steering]
        return 2 if self.config.action_mode == "discrete" else 3

    @property
    def teacher_dtype(self) -> np.dtype:
        return np.dtype(np.int64 if self.config.action_mode == "discrete" else np.float32)

    def make_teacher(self) -> DrivingTeacher | None:
        return DrivingTeacher(self.config, self.teacher) if self.teacher is not None else None

    def observations(self) -> Any:
        from dynenv_ros.envs.driving_observations import observation_builder
        options = {"max_lanes": self.max_lanes, "max_objects": self.max_objects} if self.observation == "padded" \
            else None
        return observation_builder(self.observation, self.config, self.perception, options)

    def make_world(self) -> Any:
        from dynenv_ros.driving.world import DrivingWorld
        return DrivingWorld(self.config)

    def full_observations(self, observations: Any, world: Any) -> np.ndarray:
        return observations.ground_truth.observations(world.snapshot())

    def validate_actions(self, actions: Any, num_envs: int) -> Any:
        return validate_driving_actions(actions, self.config, num_envs)

    @property
    def batch_type(self) -> type[InProcessBatch]:
        return DrivingInProcessBatch


def _storage(settings: _Settings, num_envs: int) -> dict[str, tuple[tuple[int, ...], np.dtype]]:
    """Every array a batch writes, with a leading env axis: observations ``obs/<key>``, final observations
    ``final/<key>``, learning targets ``targets/<key>`` and ``final_targets/<key>`` (``settings.targets``), and
    the per-step items."""
    obs = settings.observations()
    E, A = num_envs, settings.n_agents
    if settings.observation == "padded":
        shapes = obs.layout.shapes()
    else:
        shapes = {FULL_KEY: obs.space.shape}
    spec: dict[str, tuple[tuple[int, ...], np.dtype]] = {}
    for prefix in ("obs/", "final/"):
        spec.update({prefix + key: ((E, A) + tuple(shape), np.dtype(np.float32)) for key, shape in shapes.items()})
    if settings.targets:
        for prefix in ("targets/", "final_targets/"):
            spec.update({prefix + key: ((E, A) + shape, np.dtype(np.float32))
                         for key, shape in target_shapes(settings.config.players_per_team).items()})
    if settings.teacher is not None:
        spec["teacher"] = ((E, A, settings.action_width), settings.teacher_dtype)
    spec["reward_terms"] = ((E, N_TERMS, A), np.dtype(np.float64))
    spec["terminated"] = ((E,), np.dtype(bool))
    spec["truncated"] = ((E,), np.dtype(bool))
    spec["dropped"] = ((E, A), np.dtype(np.int64))
    spec.update(settings.batch_type.own_arrays(E, A))
    return spec


class InProcessBatch:
    """Worlds stepped one after another in this process, writing into ``arrays`` (see ``_storage``; each with a
    leading axis of ``num_envs``). A worker process runs one of these over its slice of the shared arrays. Soccer's
    worlds (team B played by the worlds themselves, learning targets); ``DrivingInProcessBatch`` driving's."""

    def __init__(self, num_envs: int, settings: _Settings, arrays: dict[str, np.ndarray] | None = None) -> None:
        if num_envs < 1:
            raise ValueError(f"num_envs must be at least 1, got {num_envs}")
        self.settings = settings
        self.config = settings.config
        # what each world's next episode is played with (``configure``: a curriculum's stage); the same team size,
        # actions and layout as ``config``
        self.episode_config = settings.config
        self.padded = settings.observation == "padded"
        self._scripted: list[Any] = []
        self._scripted_robots = range(0)
        # team B of every world played by the perceiving team: its own policies, since each remembers the ball
        self._perceiving: list[list[Any]] = []
        self._perceiving_chasers: list[list[Any]] = []
        # a league run: the member playing team B in each world this episode, drawn at each episode's start
        self.league: League | None = None
        self._league_start: dict[str, Any] | None = None     # a resumed run's league state (``start_league_from``)
        self._team_b: list[str | None] = [settings.scripted_team_b] * num_envs
        if settings.scripted_team_b is not None:
            n = self.config.players_per_team
            self._scripted_robots = range(n, 2 * n)
            league = settings.scripted_team_b == LEAGUE
            if settings.scripted_team_b == PERCEIVING_TEACHER or league:
                self._perceiving = [perceiving_team(n, self.config.period_seconds, field=self.config.field,
                                                    motion=self.config.motion) for _ in range(num_envs)]
            if league:
                self._perceiving_chasers = [perceiving_team(n, self.config.period_seconds, field=self.config.field,
                                                            motion=self.config.motion, kind="chaser")
                                            for _ in range(num_envs)]
            if settings.scripted_team_b != PERCEIVING_TEACHER:
                self._scripted = team_policies(n, "keeper_and_chasers" if league else settings.scripted_team_b,
                                               field=self.config.field, head_mode=self.config.head_mode,
                                               motion=self.config.motion)
        self.worlds = [settings.make_world() for _ in range(num_envs)]
        # one teacher per world: the perceiving teacher remembers the ball along its world's episode
        self._teachers = [settings.make_teacher() for _ in range(num_envs)]
        self.observers = [settings.observations() for _ in range(num_envs)]
        if arrays is None:
            arrays = {key: np.zeros(shape, dtype) for key, (shape, dtype) in _storage(settings, num_envs).items()}
        self.arrays = arrays
        keys = [k[4:] for k in arrays if k.startswith("obs/")]
        # Per world, views of its slice: what build_padded(out=...) fills in place.
        self._obs = [{k: arrays["obs/" + k][e] for k in keys} for e in range(num_envs)]
        self._final = [{k: arrays["final/" + k][e] for k in keys} for e in range(num_envs)]
        target_keys = [k[8:] for k in arrays if k.startswith("targets/")]
        self._targets = [{k: arrays["targets/" + k][e] for k in target_keys} or None for e in range(num_envs)]
        self._final_targets = [{k: arrays["final_targets/" + k][e] for k in target_keys} for e in range(num_envs)]

    @staticmethod
    def own_arrays(num_envs: int, n_agents: int) -> dict[str, tuple[tuple[int, ...], np.dtype]]:
        """The arrays only these worlds write, beyond every batch's (``_storage``)."""
        return {}

    @property
    def num_envs(self) -> int:
        return len(self.worlds)

    def _write_initial(self, e: int) -> None:
        """World ``e``'s first observation of an episode into its slice (its observer was just reset)."""
        world, obs = self.worlds[e], self.observers[e]
        if self.padded:
            obs.initial_padded(out=self._obs[e], targets=self._targets[e])
        else:
            self._obs[e][FULL_KEY][:] = obs.ground_truth.observations(world)

    def _observe_initial(self, e: int) -> None:
        self.observers[e].reset(self.worlds[e])
        self._write_initial(e)
        if self.league is not None:
            self._team_b[e] = self.league.draw()
        for team in (self._perceiving, self._perceiving_chasers):
            for policy in team[e] if team else ():
                policy.reset()                  # a new episode: no memory of the last one's ball
        self._label(e, episode_start=True)

    def _label(self, e: int, episode_start: bool = False) -> None:
        """World ``e``'s teacher labels of the observations just written (``envs.teacher``), if it has a teacher."""
        teacher = self._teachers[e]
        if teacher is None:
            return
        if episode_start:
            teacher.reset()
        teacher.label(self.worlds[e], self.arrays["teacher"][e], self._obs[e], self.observers[e])

    def configure(self, config: Any) -> None:
        """Each world's next episode, and every one after, is played with ``config`` (``VectorEnv.configure``);
        the episodes under way finish as they began."""
        self.episode_config = config

    def _new_episode(self, world: Any, seed: int | None) -> None:
        """``world``'s next episode, with the settings ``configure`` gave (only when they changed: a world keeps its
        settings object, and so its exact behaviour, otherwise)."""
        if world.config is self.episode_config:
            world.reset(seed=seed)
        else:
            world.reset(seed=seed, config=self.episode_config)

    def reset(self, seeds: list[int | None]) -> None:
        if self.settings.scripted_team_b == LEAGUE and self.league is None:
            known = [int(s) for s in seeds if s is not None]
            self.league = League(self.settings.league_members,
                                 np.random.default_rng(np.random.SeedSequence(known or None)))
            if self._league_start is not None:
                self.league.restore(self._league_start)
        for e, (world, seed) in enumerate(zip(self.worlds, seeds)):
            self._new_episode(world, seed)
            self._observe_initial(e)
        self.arrays["dropped"][:] = 0

    def step(self, actions: Any) -> None:
        """``actions`` already validated (``validate_actions``): one row of A actions per world."""
        terms, dropped = self.arrays["reward_terms"], self.arrays["dropped"]
        terminated, truncated = self.arrays["terminated"], self.arrays["truncated"]
        for e, (world, obs, acts) in enumerate(zip(self.worlds, self.observers, actions)):
            acts = self._with_team_b(e, list(acts))
            result = world.step(acts, on_frame=obs.on_frame)
            terms[e] = result.rewards
            if self.padded:
                terms[e, RewardTerm.OBSERVATION] += obs.build_padded(out=self._obs[e], targets=self._targets[e])
                dropped[e] = obs.dropped_rows
            else:
                self._obs[e][FULL_KEY][:] = obs.ground_truth.observations(world)
            terminated[e], truncated[e] = result.terminated, result.truncated
            if result.terminated or result.truncated:
                if self.league is not None:
                    score = world.snapshot()
                    self.league.record(str(self._team_b[e]), score.score_team_a, score.score_team_b)
                for key, final in self._final[e].items():
                    final[...] = self._obs[e][key]
                for key, final in self._final_targets[e].items():
                    final[...] = self._targets[e][key]
                self._new_episode(world, int(world.rng.integers(2**63)))
                self._observe_initial(e)
            else:
                self._label(e)

    def _with_team_b(self, e: int, acts: list[Any]) -> list[Any]:
        """World ``e``'s actions with team B's rows replaced by the team the world plays itself, if any."""
        member = self._team_b[e]
        if member is None or member == "snapshot":     # team B's rows are the caller's
            return acts
        if member in ("perceiving", "perceiving_chasers"):   # on what each robot saw last and its pose estimate
            team = self._perceiving[e] if member == "perceiving" else self._perceiving_chasers[e]
            seen, estimate = self._obs[e], self.observers[e].vision.estimate
            for i in self._scripted_robots:
                acts[i] = team[i].act({key: seen[key][i] for key in PERCEIVED_KEYS}, estimate[i])
            return acts
        snapshot = self.worlds[e].snapshot()          # a ground-truth scripted team
        for i in self._scripted_robots:
            acts[i] = self._scripted[i].act(snapshot, i)
        return acts

    def league_stats(self) -> dict[str, float]:
        """The league's per-member scores and shares ({} unless team B is the league)."""
        return {} if self.league is None else self.league.stats()

    def league_state(self) -> dict[str, Any] | None:
        """The league's scores and game counts (``League.state``; None unless team B is the league, or before reset)."""
        return None if self.league is None else self.league.state()

    def start_league_from(self, state: dict[str, Any]) -> None:
        """Carry on a league from ``state`` (a resumed run's, ``League.state``): now if it exists, else at ``reset``.
        ValueError, and nothing changed, when the state does not fit."""
        if getattr(self.settings, "scripted_team_b", None) != LEAGUE:
            raise ValueError("a league state was given, but team B of these worlds is not the league")
        League(self.settings.league_members, np.random.default_rng(0)).restore(state)   # a misfit: now, not at reset
        if self.league is not None:
            self.league.restore(state)
        else:
            self._league_start = state

    def close(self) -> None:
        pass


class DrivingInProcessBatch(InProcessBatch):
    """Driving worlds stepped in this process: no team B and no learning targets; driving_v0's per-car termination
    in ``agents_terminated`` (the world itself ignores the actions of finished cars)."""

    @staticmethod
    def own_arrays(num_envs: int, n_agents: int) -> dict[str, tuple[tuple[int, ...], np.dtype]]:
        return {"agents_terminated": ((num_envs, n_agents), np.dtype(bool))}

    def _write_initial(self, e: int) -> None:
        world, obs = self.worlds[e], self.observers[e]
        if self.padded:
            obs.initial_padded(out=self._obs[e])
        else:
            self._obs[e][FULL_KEY][:] = self.settings.full_observations(obs, world)

    def reset(self, seeds: list[int | None]) -> None:
        super().reset(seeds)
        self.arrays["agents_terminated"][:] = False

    def step(self, actions: Any) -> None:
        terms, dropped, ended = self.arrays["reward_terms"], self.arrays["dropped"], self.arrays["agents_terminated"]
        terminated, truncated = self.arrays["terminated"], self.arrays["truncated"]
        discrete = self.config.action_mode == "discrete"
        for e, (world, obs, acts) in enumerate(zip(self.worlds, self.observers, actions)):
            if isinstance(acts, np.ndarray) and discrete and acts.dtype.kind == "f":
                acts = acts.astype(np.int64)        # integral (validated): the world's fast path takes indices
            result = world.step(acts, on_frame=obs.on_frame)
            terms[e] = result.rewards
            if self.padded:
                terms[e, RewardTerm.OBSERVATION] += obs.build_padded(out=self._obs[e])
                dropped[e] = obs.dropped_rows
            else:
                self._obs[e][FULL_KEY][:] = self.settings.full_observations(obs, world)
            ended[e] = world.cars_done()
            ended[e] |= result.terminated
            terminated[e], truncated[e] = result.terminated, result.truncated
            if result.terminated or result.truncated:
                for key, final in self._final[e].items():
                    final[...] = self._obs[e][key]
                world.reset(seed=int(world.rng.integers(2**63)))
                self._observe_initial(e)
            else:
                self._label(e)


# -- actions -----------------------------------------------------------------------------------------------------

def _fast_valid(actions: np.ndarray, config: SoccerConfig) -> bool:
    """True when every row is a numeric action ``parse_action`` accepts, checked as whole arrays (no Python per
    robot); False sends the batch through ``parse_action`` for the error message."""
    kind = actions.dtype.kind
    if kind not in "iuf":
        return False
    m = config.motion
    discrete = config.head_mode == "discrete"
    if kind == "f":
        integral = actions if discrete else actions[..., :3]
        if not (np.isfinite(actions).all() and (integral == np.floor(integral)).all()):
            return False
    if discrete:       # [walk, turn, kick, head index] within 0 .. count-1
        return bool((actions >= 0).all() and (actions < (len(Walk), len(Turn), len(Kick), 2 * m.head_units + 1)).all())
    motion = actions[..., :3]
    return bool((motion >= 0).all() and (motion < (len(Walk), len(Turn), len(Kick))).all()
                and (np.abs(actions[..., 3].astype(np.float64)) <= m.head_step * m.head_units + 1e-9).all())


def validate_driving_actions(actions: Any, config: DrivingConfig, num_envs: int) -> Any:
    """Check a batch of driving actions before any world moves: the array itself when every row is valid (discrete
    (E, A, 2) integral indices 0..2; continuous (E, A, 3) [throttle, brake, steering] within the bounds), else the
    parsed ``DrivingAction``s; ValueError names the env, the car and the field."""
    from dynenv_ros.driving.cars import parse_action as parse_driving_action
    arr = np.asarray(actions)
    discrete = config.action_mode == "discrete"
    width = 2 if discrete else 3
    expected = (num_envs, config.n_cars)
    if arr.shape[:2] != expected:
        raise ValueError(f"actions must have shape {expected + (width,)}, got {arr.shape}")
    if arr.shape == expected + (width,) and arr.dtype.kind in "iuf" and np.isfinite(arr).all():
        if discrete:
            if (arr == np.floor(arr)).all() and (arr >= 0).all() and (arr < 3).all():
                return arr
        else:
            w = config.cars.max_yaw_rate
            low, high = np.array([-1.0, 0.0, -w]), np.array([1.0, 1.0, w])
            if (arr >= low).all() and (arr <= high).all():
                return arr
    w = config.cars.max_yaw_rate
    return [[parse_driving_action(f"env {e} car {i}", raw, mode=config.action_mode, max_yaw_rate=w)
             for i, raw in enumerate(row)] for e, row in enumerate(arr)]


def validate_actions(actions: Any, config: SoccerConfig, num_envs: int) -> Any:
    """Check a whole batch of actions before any world moves: the array itself when every row is valid, else the
    parsed ``SoccerAction``s; ValueError names the env, the robot and the field."""
    arr = np.asarray(actions)
    expected = (num_envs, config.n_robots)
    if arr.shape[:2] != expected:
        raise ValueError(f"actions must have shape {expected + (4,)}, got {arr.shape}")
    if arr.shape == expected + (4,) and _fast_valid(arr, config):
        return arr
    m = config.motion
    return [[parse_action(f"env {e} robot {i}", raw, head_mode=config.head_mode, head_step=m.head_step,
                          head_units=m.head_units) for i, raw in enumerate(row)] for e, row in enumerate(arr)]


# -- shared memory and workers -----------------------------------------------------------------------------------

STEP = b"s"      # parent -> worker: step with the actions in the shared block; anything else is a pickled command
OK = b""         # worker -> parent: done; anything else is a pickled exception


def _worker(conn: Connection, blocks: dict[str, tuple[str, tuple[int, ...], str]], start: int, count: int,
            settings: _Settings, core: int | None = None) -> None:
    if core is not None:
        os.sched_setaffinity(0, [core])
    attached = [shared_memory.SharedMemory(name=name) for name, _, _ in blocks.values()]
    try:
        arrays = {key: np.ndarray(shape, np.dtype(dtype), buffer=shm.buf)[start:start + count]
                  for (key, (_, shape, dtype)), shm in zip(blocks.items(), attached)}
        actions = arrays.pop("actions")
        batch = settings.batch_type(count, settings, arrays)
        while True:
            try:
                message = conn.recv_bytes()
            except (EOFError, OSError):     # the parent is gone
                return
            try:
                if message == STEP:
                    batch.step(actions)
                else:
                    command, payload = pickle.loads(message)
                    if command == "close":
                        conn.send_bytes(OK)
                        return
                    # seeds / parsed actions / the settings of the next episodes
                    {"reset": batch.reset, "step": batch.step, "configure": batch.configure}[command](payload)
                conn.send_bytes(OK)
            except Exception as exc:     # report to the parent, keep serving
                try:
                    reply = pickle.dumps(exc)
                except Exception:       # not picklable
                    reply = pickle.dumps(RuntimeError(f"{type(exc).__name__}: {exc}"))
                conn.send_bytes(reply)
    finally:
        arrays = actions = batch = None       # drop the views before closing the blocks
        for shm in attached:
            try:
                shm.close()
            except BufferError:
                pass


def _shutdown(conns: list[Connection], procs: list[Any], shared: SharedArrays | None) -> None:
    for conn in conns:
        try:
            conn.send_bytes(pickle.dumps(("close", None)))
        except OSError:
            pass
    for conn in conns:
        try:
            if conn.poll(5):
                conn.recv_bytes()
        except (EOFError, OSError):
            pass
        conn.close()
    for proc in procs:
        proc.join(timeout=5)
        if proc.is_alive():
            proc.kill()
            proc.join(timeout=5)
    if shared is not None:
        shared.close()


class SubprocessBatch:
    """Worlds split into ``workers`` shards (default one per CPU this process may use, ``self.sizes``) stepped
    concurrently. With ``parent_steps`` and at least two shards this process steps the first shard itself while a
    worker process steps each of the others: its core works instead of sleeping through the step (8 worlds on 2
    cores: ≈ 0.95 of what two independent processes give instead of ≈ 0.88, `dynenv-bench vector`); else every
    shard has a worker. Every array lives in shared memory (``self.arrays``, actions included), this process's
    shard writing into its slice like a worker; the pipes carry commands only. ``pin_workers``: the worker of shard
    s runs only on the s-th of those CPUs (no migrations between steps); this process itself is never pinned (it is
    the caller's)."""

    def __init__(self, num_envs: int, settings: _Settings, workers: int | None = None,
                 pin_workers: bool = False, parent_steps: bool = True) -> None:
        if num_envs < 1:
            raise ValueError(f"num_envs must be at least 1, got {num_envs}")
        cpus = sorted(os.sched_getaffinity(0))
        shards = min(num_envs, workers or len(cpus))
        self.config = settings.config
        self.num_envs = num_envs
        self.scenario = settings.scenario
        # The larger shards first: with parent_steps this process's, which starts at once, while a worker's start
        # and answer wait for wake-ups (5 worlds on 2 cores: 3 here and 2 in the worker beat 2 and 3 by 2-8 %).
        self.sizes = [num_envs // shards + (1 if s < num_envs % shards else 0) for s in range(shards)]
        # Worlds 0 .. parent_envs-1 are stepped here (the first shard, or none); every other shard has a worker.
        self.parent_envs = self.sizes[0] if parent_steps and shards > 1 else 0
        self._local: InProcessBatch | None = None
        self._conns: list[Connection] = []
        self._procs: list[Any] = []
        self._awaiting = False
        spec = _storage(settings, num_envs)
        spec["actions"] = ((num_envs, settings.n_agents, settings.action_width), np.dtype(np.float64))  # each step
        self._shared = SharedArrays(spec)
        self._finalizer = weakref.finalize(self, _shutdown, self._conns, self._procs, self._shared)
        self.arrays = self._shared.arrays
        try:
            context = mp.get_context("forkserver")
            names = self._shared.names()
            start = self.parent_envs
            for s in range(1 if self.parent_envs else 0, shards):
                parent, child = context.Pipe()
                self._conns.append(parent)
                core = cpus[s % len(cpus)] if pin_workers else None
                proc = context.Process(target=_worker, args=(child, names, start, self.sizes[s], settings, core),
                                       daemon=True)
                proc.start()
                child.close()
                self._procs.append(proc)
                start += self.sizes[s]
            if self.parent_envs:        # built while the workers start
                self._local = settings.batch_type(self.parent_envs, settings, {
                    key: array[:self.parent_envs] for key, array in self.arrays.items() if key != "actions"})
        except BaseException:
            self._finalizer()
            raise

    def _call(self, messages: list[bytes], local: Callable[[], None] | None = None) -> None:
        """Send each worker its message, run ``local`` (the parent's shard) meanwhile, then wait for every reply."""
        if self._awaiting:
            raise RuntimeError(f"an earlier call to the {self.scenario} workers was interrupted, so their replies are "
                               "out of step; close() this env and make a new one")
        self._awaiting = True              # until every reply is in (not so after a KeyboardInterrupt mid-step)
        sent, errors, died = [], [], None
        for w, (conn, message) in enumerate(zip(self._conns, messages)):
            try:
                conn.send_bytes(message)
                sent.append(w)
            except OSError as exc:        # BrokenPipeError: the worker is gone
                died = died or (w, exc)
        if local is not None and not died:
            try:
                local()
            except Exception as exc:       # the workers still answer first, keeping the pipes in step
                errors.append(exc)
        for w in sent:                    # every worker that got the command answers, keeping the pipes in step
            try:
                reply = self._conns[w].recv_bytes()
            except (EOFError, OSError) as exc:
                died = died or (w, exc)
                continue
            if reply != OK:
                errors.append(pickle.loads(reply))
        self._awaiting = False
        if died:
            w, exc = died
            raise RuntimeError(f"{self.scenario} worker process {w} died ({exc!r}); see its error output above. Scripts "
                               "that start workers need an `if __name__ == '__main__':` guard") from exc
        if errors:
            raise errors[0]

    def _command(self, command: str, payload: Any) -> None:
        """``payload`` split by world: the parent's part run here, each worker's part pickled to it."""
        parts = self._split(payload)
        local = partial(getattr(self._local, command), parts.pop(0)) if self._local is not None else None
        self._call([pickle.dumps((command, part)) for part in parts], local)

    def _split(self, items: Any) -> list[Any]:
        bounds = np.cumsum([0] + self.sizes)
        return [items[a:b] for a, b in zip(bounds[:-1], bounds[1:])]

    def reset(self, seeds: list[int | None]) -> None:
        self._command("reset", seeds)

    def configure(self, config: Any) -> None:
        """Every shard's worlds play their next episodes with ``config`` (``InProcessBatch.configure``)."""
        local = partial(self._local.configure, config) if self._local is not None else None
        self._call([pickle.dumps(("configure", config))] * len(self._conns), local)

    def step(self, actions: Any) -> None:
        if isinstance(actions, np.ndarray):       # numeric and valid: through shared memory
            p = self.parent_envs
            self.arrays["actions"][p:] = actions[p:]
            local = partial(self._local.step, actions[:p]) if self._local is not None else None
            self._call([STEP] * len(self._conns), local)
        else:                                     # parsed SoccerActions (rare forms): pickled
            self._command("step", actions)

    def close(self) -> None:
        self.arrays = {}
        self._local = None          # its views of the blocks go before the blocks are closed
        self._finalizer()


class VectorEnv:
    """What every batch of worlds shares (``SoccerVectorEnv``, ``DrivingVectorEnv``): ``reset(seed)``,
    ``step(actions) -> BatchStep``, ``close()``; the scenario's class checks its settings and calls ``_start``."""

    def _start(self, settings: Any, observations: Any, num_envs: int, backend: str, workers: int | None,
               pin_workers: bool, parent_steps: bool, copy: bool) -> None:
        self._settings = settings
        self.observation = settings.observation
        self.layout: PaddedLayout | None = observations.layout if settings.observation == "padded" else None
        self.single_observation_space = observations.space
        if backend == "auto":
            backend = "subprocess" if num_envs >= AUTO_SUBPROCESS_MIN_ENVS[settings.observation] \
                and len(os.sched_getaffinity(0)) > 1 else "inprocess"
        if backend == "inprocess":
            self._batch: InProcessBatch | SubprocessBatch = settings.batch_type(num_envs, settings)
        elif backend == "subprocess":
            self._batch = SubprocessBatch(num_envs, settings, workers, pin_workers, parent_steps)
        else:
            raise ValueError(f"backend must be 'auto', 'inprocess' or 'subprocess', got {backend!r}")
        self.backend = backend
        self.num_envs = num_envs
        self.copy = copy
        arrays = self._batch.arrays
        self._keys = [k[4:] for k in arrays if k.startswith("obs/")]
        self._target_keys = [k[8:] for k in arrays if k.startswith("targets/")]
        self.with_targets = bool(settings.targets)
        self.teacher = settings.teacher
        self._was_reset = self._closed = False

    def _observation(self, prefix: str, index: Any = slice(None), copy: bool = True) -> Observation:
        arrays = self._batch.arrays
        if self.observation == "full":
            value = arrays[prefix + FULL_KEY][index]
            return value.copy() if copy else value
        return {k: arrays[prefix + k][index].copy() if copy else arrays[prefix + k][index] for k in self._keys}

    def _targets(self, prefix: str, index: Any = slice(None), copy: bool = True) -> dict[str, np.ndarray]:
        arrays = self._batch.arrays
        return {k: arrays[prefix + k][index].copy() if copy else arrays[prefix + k][index] for k in self._target_keys}

    @property
    def targets(self) -> dict[str, np.ndarray]:
        """The learning targets of the observations returned last (by ``reset()`` or ``step()``), copied."""
        self._check_open()
        if not self.with_targets:
            raise RuntimeError(f"this {type(self).__name__} was made without targets=True")
        if not self._was_reset:
            raise RuntimeError("no targets before reset(); call reset(seed) first")
        return self._targets("targets/")

    @property
    def teacher_actions(self) -> np.ndarray:
        """The teacher's (E, A, width) labels of the observations returned last, copied (``BatchStep``)."""
        self._check_open()
        if self.teacher is None:
            raise RuntimeError(f"this {type(self).__name__} was made without a teacher")
        if not self._was_reset:
            raise RuntimeError("no teacher labels before reset(); call reset(seed) first")
        return self._batch.arrays["teacher"].copy()

    def league_stats(self) -> dict[str, float]:
        """A league run's per-member scores and shares, from worlds stepped in this process ({} otherwise)."""
        return self._batch.league_stats() if isinstance(self._batch, InProcessBatch) else {}

    def league_state(self) -> dict[str, Any] | None:
        """A league run's scores and game counts, to checkpoint (worlds stepped in this process; None otherwise)."""
        return self._batch.league_state() if isinstance(self._batch, InProcessBatch) else None

    def start_league_from(self, state: dict[str, Any]) -> None:
        """Carry on the league of a resumed run (worlds stepped in this process only: ValueError otherwise)."""
        if not isinstance(self._batch, InProcessBatch):
            raise ValueError("a league state can be restored only in worlds stepped in this process")
        self._batch.start_league_from(state)

    def _check_open(self) -> None:
        if self._closed:
            raise RuntimeError(f"{type(self).__name__} is closed")

    def reset(self, seed: int | None = None) -> Observation:
        self._check_open()
        self._batch.reset(_seeds(seed, self.num_envs))
        self._was_reset = True
        return self._observation("obs/", copy=self.copy)

    def step(self, actions: Any) -> BatchStep:
        self._check_open()
        valid = self._settings.validate_actions(actions, self.num_envs)   # before any world moves
        if not self._was_reset:
            raise RuntimeError(f"{type(self).__name__}.step() before reset(); call reset(seed) first")
        self._batch.step(valid)
        arrays = self._batch.arrays
        terms = arrays["reward_terms"].copy()
        terminated, truncated = arrays["terminated"].copy(), arrays["truncated"].copy()
        ended = [int(e) for e in np.flatnonzero(terminated | truncated)]
        finals = {e: self._observation("final/", e) for e in ended}
        if not self.with_targets:
            targets, final_targets = None, {}
        else:
            targets = self._targets("targets/", copy=self.copy)
            final_targets = {e: self._targets("final_targets/", e) for e in ended}
        teacher = arrays["teacher"].copy() if self.teacher is not None else None
        agents_terminated = arrays["agents_terminated"].copy() if "agents_terminated" in arrays else None
        return BatchStep(self._observation("obs/", copy=self.copy), terms.sum(axis=1), terms, terminated,
                         truncated, finals, arrays["dropped"].copy(), targets, final_targets, teacher,
                         agents_terminated)

    def close(self) -> None:
        self._closed = True
        self._batch.close()

    def __enter__(self) -> "VectorEnv":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()


class SoccerVectorEnv(VectorEnv):
    """``num_envs`` soccer worlds as one batch: ``reset(seed)`` and ``step(actions (E, A, 4)) -> BatchStep``.

    ``observation="padded"`` (default): perceived detections as ``{key: (E, A, ...)}`` float32 arrays
    (``self.layout``, ``self.single_observation_space``), perception as ``robocup_v0``'s ``perception`` argument;
    ``"full"``: ground truth (E, A, D). ``copy=False`` returns the batch's own arrays, overwritten by the next step.
    Subprocess backend: the worlds split into ``workers`` shards (default one per CPU this process may use), each
    stepped by a worker process, except that with ``parent_steps=True`` (the default, when ``workers`` ≥ 2) this
    process steps the first shard itself meanwhile, instead of sleeping until the workers answer — faster, and
    bit-identical; ``parent_steps=False`` gives every shard a worker (``workers`` processes). ``pin_workers=True``
    pins the worker of shard s to the s-th of those CPUs (this process is never pinned).

    ``targets=True`` (padded only): every world also writes the self-supervised localization and reconstruction
    targets of its robots (``envs.learning_targets``: ``pose`` (E, A, 6), ``ball`` (E, A, 3), ``robots`` (E, A, R, 6),
    ``ball_seen`` (E, A), ``robots_seen`` (E, A, R), float32, team frame), of the same instant as the observations:
    ``BatchStep.targets`` and ``final_targets`` after a step, ``self.targets`` for the observations returned last
    (after ``reset()`` too). Shapes without the (E, A) axes: ``self.target_shapes``.

    ``scripted_team_b="chaser"`` or ``"keeper_and_chasers"``: every world drives its team B robots with that scripted
    team (``soccer.scripted``, reading the world's own ground truth in the world's process), and the rows given
    for those robots are ignored (send zeros). Why in the worlds: a scripted policy needs the ground truth, which
    would otherwise have to cross the process boundary every step. ``"perceiving"`` (padded only): team B is the
    perceiving keeper_and_chasers team (``soccer.perceiving``), each robot acting on its own padded observation of
    the last period and its pose estimate, with a ball memory per world that starts afresh each episode; the
    self-localization runs for it. ``"league"`` (padded only): each world's team B is drawn every episode from the
    league's members (``envs.league``; ``league_members``: some of them, default all).

    ``localization="estimate"`` (padded only): every world runs the emulated self-localization and the observations
    gain ``pose_estimate`` (E, A, 7), the team-frame pose estimate of the period's last frame (``envs.pose_features``);
    ``"none"`` (default): nothing changes.

    ``teacher="chaser"``, ``"eager_chaser"`` or ``"keeper_and_chasers"``: every world also labels each robot with
    that scripted team's action for the state its observation shows (``envs.teacher``), as (E, A, 4) discrete action
    indices: ``BatchStep.teacher_actions``, and ``self.teacher_actions`` for the observations returned last.
    ``teacher="perceiving"`` (padded only): the label is the perceiving chaser's (``soccer.perceiving``), computed
    from exactly the robot's padded observation and its pose estimate, with a ball memory that starts afresh with
    each episode of its world; every world runs its self-localization for it, even with ``localization="none"``
    (the observations then do not carry the estimate the teacher used).
    """

    def __init__(self, num_envs: int, backend: str = "auto", workers: int | None = None,
                 config: SoccerConfig | Mapping[str, Any] | None = None, observation: str = "padded",
                 perception: str | Mapping[str, Any] | PerceptionParams = "realistic",
                 max_landmarks: int | None = None, max_objects: int | None = None, copy: bool = True,
                 pin_workers: bool = False, targets: bool = False, scripted_team_b: str | None = None,
                 teacher: str | None = None, parent_steps: bool = True, localization: str = "none",
                 league_members: Sequence[str] | None = None) -> None:
        self.config = config if isinstance(config, SoccerConfig) else SoccerConfig.from_mapping(config)
        members = LEAGUE_MEMBERS if league_members is None else tuple(league_members)
        if league_members is not None and scripted_team_b != LEAGUE:
            raise ValueError(f"league_members applies to scripted_team_b='league', got {scripted_team_b!r}")
        League(members, np.random.default_rng(0))         # unknown or no members: ValueError now
        if observation not in VECTOR_OBSERVATIONS:
            raise ValueError(f"observation must be one of {VECTOR_OBSERVATIONS}, got {observation!r}")
        if num_envs < 1:
            raise ValueError(f"num_envs must be at least 1, got {num_envs}")
        if targets and observation != "padded":
            raise ValueError(f"targets=True needs observation='padded' (the targets come with perception), "
                             f"got observation={observation!r}")
        if scripted_team_b not in SCRIPTED_TEAMS_B:
            raise ValueError(f"scripted_team_b must be one of {SCRIPTED_TEAMS_B}, got {scripted_team_b!r}")
        if scripted_team_b in (PERCEIVING_TEACHER, LEAGUE) and observation != "padded":
            raise ValueError(f"scripted_team_b={scripted_team_b!r} acts on each robot's perceived observation and pose "
                             f"estimate: it needs observation='padded', got observation={observation!r}")
        if teacher is not None and teacher not in TEACHERS:
            raise ValueError(f"teacher must be None or one of {TEACHERS}, got {teacher!r}")
        if teacher is not None and self.config.head_mode != "discrete":
            raise ValueError("teacher labels need head_mode='discrete' (the agent's head is then an index)")
        if teacher == PERCEIVING_TEACHER and observation != "padded":
            raise ValueError("teacher='perceiving' acts on each robot's perceived observation and pose estimate: it "
                             f"needs observation='padded', got observation={observation!r}")
        if not isinstance(parent_steps, bool):
            raise ValueError(f"parent_steps must be True or False, got {parent_steps!r}")
        if localization not in LOCALIZATION_OPTIONS:
            raise ValueError(f"localization must be one of {LOCALIZATION_OPTIONS}, got {localization!r}")
        settings = _Settings(self.config, observation, perception_params(perception), max_landmarks, max_objects,
                             bool(targets), scripted_team_b, teacher, localization, members)
        observations = settings.observations()      # checks the layout maxima; gives the spaces
        self._start(settings, observations, num_envs, backend, workers, pin_workers, parent_steps, copy)
        self.target_shapes: dict[str, tuple[int, ...]] | None = \
            target_shapes(self.config.players_per_team) if targets else None

    def configure(self, config: SoccerConfig | Mapping[str, Any]) -> None:
        """From each world's next episode on, play with ``config`` (a ``SoccerConfig``, or settings as a mapping)
        instead of the settings the env was made with: another start (``start``, docs/soccer.md "Start states") or
        episode length (``episode_seconds``) — a curriculum's next stage. Everything else (team size, rates,
        motions, rules, rewards) must stay as it is: observations, actions and spaces do not change. The episodes
        under way finish as they began."""
        new = config if isinstance(config, SoccerConfig) else SoccerConfig.from_mapping(config)
        if replace(new, start=self.config.start, episode_seconds=self.config.episode_seconds) != self.config:
            raise ValueError("configure changes only start and episode_seconds of the settings the env was made "
                             "with (team size, rates, motions, rules and rewards stay)")
        self._check_open()
        self._batch.configure(new)

    def __enter__(self) -> "SoccerVectorEnv":
        return self


class DrivingVectorEnv(VectorEnv):
    """``num_envs`` driving worlds as one batch: ``reset(seed)`` and ``step(actions) -> BatchStep``, over cars.

    ``observation="padded"`` (default): each car's perceived detections (``driving_v0(observation="padded")``) as
    ``{key: (E, A, ...)}`` float32 arrays (``self.layout``: driving's ``PaddedLayout``; ``max_lanes``,
    ``max_objects`` its maxima), ``perception`` as ``driving_v0``'s (a preset name, a mapping, params; None:
    realistic); ``"full"``: the ground truth (E, A, D), no perception. ``config``: a ``DrivingConfig`` or its settings
    as a mapping. Actions (E, A, 2) discrete indices or (E, A, 3) [throttle, brake, steering] by
    ``config.action_mode``. ``BatchStep.agents_terminated`` (E, A): the car can earn nothing more this episode
    (driving_v0's per-car termination); its later actions are ignored by its world and its transitions until the
    episode ends carry no reward. Backends, shards, ``copy`` and automatic resets as ``SoccerVectorEnv``.
    ``teacher="scripted"``: every world also labels each car with the scripted driver's action for the state its
    observation shows (``envs.teacher.DrivingTeacher``; (E, A, 2) indices, or (E, A, 3) normalised commands when
    continuous): ``BatchStep.teacher_actions`` and ``self.teacher_actions``."""

    def __init__(self, num_envs: int, backend: str = "auto", workers: int | None = None,
                 config: DrivingConfig | Mapping[str, Any] | None = None, observation: str = "padded",
                 perception: Any = None, max_lanes: int | None = None, max_objects: int | None = None,
                 copy: bool = True, pin_workers: bool = False, parent_steps: bool = True,
                 teacher: str | None = None) -> None:
        from dynenv_ros.envs.driving_observations import driving_perception_params
        self.config = config if isinstance(config, DrivingConfig) else DrivingConfig.from_mapping(config or {})
        if teacher is not None and teacher not in DRIVING_TEACHERS:
            raise ValueError(f"teacher must be None or one of {DRIVING_TEACHERS}, got {teacher!r}")
        if observation not in VECTOR_OBSERVATIONS:
            raise ValueError(f"observation must be one of {VECTOR_OBSERVATIONS}, got {observation!r}")
        if isinstance(num_envs, bool) or not isinstance(num_envs, (int, np.integer)) or num_envs < 1:
            raise ValueError(f"num_envs must be at least 1, got {num_envs}")
        if not isinstance(parent_steps, bool):
            raise ValueError(f"parent_steps must be True or False, got {parent_steps!r}")
        if observation == "full" and (perception is not None or max_lanes is not None or max_objects is not None):
            raise ValueError("observation='full' is noise-free ground truth: perception, max_lanes and max_objects "
                             "apply to observation='padded'")
        params = driving_perception_params(perception) if observation == "padded" else None
        settings = _DrivingSettings(self.config, observation, params, max_lanes, max_objects, teacher)
        observations = settings.observations()      # checks the layout maxima; gives the spaces
        self._start(settings, observations, int(num_envs), backend, workers, pin_workers, parent_steps, copy)

    def __enter__(self) -> "DrivingVectorEnv":
        return self
