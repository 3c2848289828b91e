"""The soccer world served to asynchronous controllers (ROS nodes, sockets, tests): actions arrive one robot at a
time, are validated and kept per motion period; a period runs when all controlled robots have acted, or when told
to. ROS-free: the simulator node (``nodes/sim_node.py``) only converts what comes in and goes out.
"""
from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from dynenv_ros.perception.model import missed_objects
from dynenv_ros.perception.params import PerceptionParams
from dynenv_ros.sim.ground_truth import WorldSnapshot
from dynenv_ros.sim.reward_terms import RewardTerm
from dynenv_ros.sim.seeding import checked_seed
from dynenv_ros.soccer.actions import IDLE, Kick, SoccerAction, Turn, Walk
from dynenv_ros.soccer.config import SoccerConfig
from dynenv_ros.soccer.vision import SoccerVision
from dynenv_ros.soccer.world import TEAM_A, TEAM_B, SoccerWorld

MISSING_ACTION_RULES = ("hold", "none")
REJECT_REASONS = ("malformed", "out_of_range", "unknown_robot", "wrong_episode", "late", "early", "duplicate")


@dataclass
class RobotFrame:
    """What one robot perceived at one vision instant, plus its own state and what the GameController told it."""
    detections: np.ndarray        # structured DETECTION_DTYPE rows (camera frame)
    head_yaw: float
    fallen: bool
    penalized: bool
    kicking: bool                 # executing a kick
    ball_owner: int               # set-play / kick-off ownership relative to its team: +1 own, -1 opponents, 0 free
    ball_owner_seconds: float     # seconds left of that ownership (0 when free)
    game_seconds_remaining: float
    missed: np.ndarray | None = None   # (m, 2) field positions of objects in view but not detected, if asked for


@dataclass
class FrameOutput:
    tick: int
    frame_index: int
    snapshot: WorldSnapshot
    robots: list[RobotFrame]


@dataclass
class RobotFeedback:
    rewards: dict[str, float]
    seen_object_ids: list[int]
    landmarks_seen: float


@dataclass
class PeriodOutput:
    episode_id: int
    motion_period: int            # the period that just ran
    frames: list[FrameOutput]
    feedback: list[RobotFeedback]
    terminated: bool
    truncated: bool
    events: list = field(default_factory=list)


def refusal_key(reason: str) -> str:
    """The counter a refusal reason is counted under: ``rejected_<kind>``, or ``ignored_after_episode_end``."""
    return "ignored_after_episode_end" if reason.startswith("ignored") else "rejected_" + reason.split(":")[0]


class SoccerSession:
    """One world, its perception, and a mailbox of actions per motion period."""

    def __init__(self, config: SoccerConfig, perception: PerceptionParams, seed: int | None = None,
                 missing_action: str = "none", controlled: list[int] | None = None) -> None:
        if missing_action not in MISSING_ACTION_RULES:
            raise ValueError(f"missing_action must be one of {MISSING_ACTION_RULES}, got {missing_action!r}")
        self.config = config
        self.names = config.robot_names
        self.world = SoccerWorld(config, seed=seed)
        self.perception = perception
        self.vision = SoccerVision(self.world, perception)
        self.missing_action = missing_action
        self.controlled = sorted(set(range(config.n_robots) if controlled is None else controlled))
        for robot in self.controlled:
            if not 0 <= robot < config.n_robots:
                raise ValueError(f"controlled robot {robot} does not exist (robots 0..{config.n_robots - 1})")
        self.pending: dict[int, SoccerAction] = {}
        self.last: dict[int, SoccerAction] = {}
        self.counts: Counter[str] = Counter()
        self.accepted_per_robot: Counter[int] = Counter()
        self.finished = False
        self._previous_episode, self._previous_final_period = -1, -1
        self.missed_for: int | None = None      # a robot whose misses each frame reports (visualisation)

    # -- episode -----------------------------------------------------------------------------------------------
    def reset(self, seed: int | None = None, kickoff_team: int = TEAM_A) -> int:
        seed = checked_seed(seed)
        if kickoff_team not in (TEAM_A, TEAM_B) or isinstance(kickoff_team, bool):
            raise ValueError(f"kickoff_team must be {TEAM_A} (team A) or {TEAM_B} (team B), got {kickoff_team!r}")
        # Policies answer an episode's last frames before they see the next episode: expect those answers.
        self._previous_episode, self._previous_final_period = self.world.episode_id, self.world.period
        self.world.reset(seed=seed, kickoff_team=kickoff_team)
        self.vision.reset()
        self.pending.clear()
        self.last.clear()
        self.finished = False
        return self.world.episode_id

    @property
    def episode_id(self) -> int:
        return self.world.episode_id

    @property
    def period(self) -> int:
        """The motion period whose actions are being collected. Period 0 is the observation of the reset state;
        the frames of period p are what the policy sees before acting for period p + 1 (Action.msg)."""
        return self.world.period + 1

    # -- actions -------------------------------------------------------------------------------------------------
    def submit(self, robot_id: int, episode_id: int, motion_period: int, walk: int, turn: int, kick: int,
               head_yaw_delta: float) -> tuple[bool, str]:
        """Accept one robot's action for the current period, or refuse it with a reason (counted)."""
        reason = self.check(robot_id, episode_id, motion_period, walk, turn, kick, head_yaw_delta)
        if reason:
            self.counts[refusal_key(reason)] += 1
            return False, reason
        self.pending[robot_id] = SoccerAction(Walk(walk), Turn(turn), Kick(kick), float(head_yaw_delta))
        self.counts["accepted"] += 1
        self.accepted_per_robot[robot_id] += 1
        return True, "accepted"

    def check(self, robot_id: int, episode_id: int, motion_period: int, walk: int, turn: int, kick: int,
              head_yaw_delta: float) -> str:
        """Why this action would be refused now ("" if it would be accepted). Reads the state and changes nothing,
        so another thread may screen actions with it (the ROS simulator's action inbox)."""
        return self._check(robot_id, episode_id, motion_period, walk, turn, kick, head_yaw_delta)

    def _check(self, robot_id, episode_id, motion_period, walk, turn, kick, head) -> str:
        if not 0 <= robot_id < self.config.n_robots:
            return f"unknown_robot: robot {robot_id} does not exist"
        if self.finished and episode_id == self.episode_id and motion_period == self.period:
            # The answers to an episode's last frames: no period of this episode will run them.
            return "ignored: the episode has finished"
        if episode_id != self.episode_id:
            if episode_id == self._previous_episode and motion_period == self._previous_final_period + 1:
                return "ignored: an answer to the previous episode's last frames"
            return f"wrong_episode: episode {episode_id}, the current one is {self.episode_id}"
        if motion_period < self.period:
            return f"late: period {motion_period} has run already (now collecting {self.period})"
        if motion_period > self.period:
            return f"early: period {motion_period} is not the current one ({self.period})"
        if robot_id in self.pending:
            return f"duplicate: robot {robot_id} already acted in period {motion_period}"
        if not isinstance(head, (int, float)) or not math.isfinite(head):
            return f"malformed: head_yaw_delta is {head}"
        limits = (("walk", walk, len(Walk)), ("turn", turn, len(Turn)), ("kick", kick, len(Kick)))
        for name, value, count in limits:
            if not 0 <= value < count:
                return f"out_of_range: {name}={value} (0..{count - 1})"
        bound = self.config.motion.head_max_delta
        if abs(head) > bound + 1e-6:
            return f"out_of_range: head_yaw_delta={head:.3f} rad beyond ±{bound:.3f}"
        return ""

    def ready(self) -> bool:
        """Every controlled robot has acted for the current period."""
        return all(robot in self.pending for robot in self.controlled)

    # -- one period ----------------------------------------------------------------------------------------------
    def initial(self) -> PeriodOutput:
        """Period 0: every frame shows the reset state (each perceived anew), no rewards yet."""
        frames = self.config.rates.frames_per_period
        snapshot = self.world.snapshot()
        for k in range(frames):
            self.vision.frame(k)
        return self._output(0, [snapshot] * frames, [self.world.tick] * frames, self.vision.perceive(),
                            np.zeros((len(RewardTerm), self.config.n_robots)), False, False, [])

    def step(self) -> PeriodOutput:
        """Run the current period with the actions received; missing ones follow ``missing_action``."""
        if self.finished:
            raise RuntimeError("the episode has finished; reset first")
        actions = []
        for robot in range(self.config.n_robots):
            action = self.pending.get(robot)
            if action is None:
                if robot in self.controlled:
                    self.counts["missing"] += 1
                action = self.last.get(robot, IDLE) if self.missing_action == "hold" else IDLE
            actions.append(action)
        snapshots: list[WorldSnapshot] = []
        ticks: list[int] = []

        def on_frame(k: int) -> None:
            self.vision.frame(k)
            snapshots.append(self.world.snapshot())
            ticks.append(self.world.tick)

        result = self.world.step(actions, on_frame=on_frame)
        perception = self.vision.perceive()
        result.rewards[RewardTerm.OBSERVATION] += self.vision.observation_rewards(perception)
        self.last = dict(enumerate(actions))
        self.pending.clear()
        self.finished = result.terminated or result.truncated
        return self._output(self.world.period, snapshots, ticks, perception, result.rewards, result.terminated,
                            result.truncated, result.events)

    def _output(self, period, snapshots, ticks, perception, rewards, terminated, truncated, events) -> PeriodOutput:
        n = self.config.n_robots
        proprio = self.vision.proprioception.tolist()        # (F, n, 4): head yaw, fallen, penalized, kicking
        controller = self.vision.game_controller.tolist()    # (F, n, 3): owner relation, its seconds, game seconds
        frames = [FrameOutput(ticks[k], k, snapshots[k],
                              [RobotFrame(perception.of_view(k * n + i), proprio[k][i][0], bool(proprio[k][i][1]),
                                          bool(proprio[k][i][2]), bool(proprio[k][i][3]), int(controller[k][i][0]),
                                          controller[k][i][1], controller[k][i][2],
                                          self._missed(perception, k, k * n + i) if i == self.missed_for else None)
                               for i in range(n)])
                  for k in range(len(snapshots))]
        ids = self.vision.objects.object_id
        landmarks = self.vision.landmarks_seen(perception).mean(axis=0)           # (n,)
        feedback = []
        for i in range(n):
            seen = perception.seen[i::n].any(axis=0)
            feedback.append(RobotFeedback({t.name.lower(): float(rewards[t, i]) for t in RewardTerm},
                                          [int(x) for x in ids[seen]], float(landmarks[i])))
        return PeriodOutput(self.episode_id, period, frames, feedback, terminated, truncated, events)


    def _missed(self, perception, frame: int, view: int) -> np.ndarray:
        missed = missed_objects(perception.visible[view], perception.of_view(view), self.vision.objects.object_id)
        x, y = self.vision.positions(frame)
        return np.column_stack((x[missed], y[missed]))


def kickoff_team(value: Any) -> int:
    """'a' / 'b' (or the team signs 1 / -1) → the team sign; anything else is refused with the reason (a list or a
    mapping used to reach a dict lookup and crash the caller with an unhashable-type TypeError)."""
    if isinstance(value, str) and value in ("a", "b"):
        return TEAM_A if value == "a" else TEAM_B
    if isinstance(value, (int, np.integer)) and not isinstance(value, bool) and int(value) in (TEAM_A, TEAM_B):
        return int(value)
    raise ValueError(f"kickoff_team must be 'a' or 'b', got {value!r} ({type(value).__name__})")
