"""The soccer world served to asynchronous controllers (ROS nodes, sockets, tests): actions arrive one robot at a
time, are validated and kept per motion period; a period runs when all controlled robots have acted, or when told
to. ROS-free: the simulator node's game (``sim_game.py``) serves it, and the node (``nodes/sim_node.py``) only
converts what comes in and goes out.
"""
from __future__ import annotations

import math
from typing import Any

import numpy as np

from dynenv_ros.envs.session import (MISSING_ACTION_RULES, REJECT_REASONS, ActionSession, FrameOutput,  # noqa: F401
                                     PeriodOutput, RobotFeedback, RobotFrame, refusal_key)
from dynenv_ros.perception.model import missed_objects
from dynenv_ros.perception.params import PerceptionParams
from dynenv_ros.sim.ground_truth import WorldSnapshot
from dynenv_ros.sim.reward_terms import RewardTerm
from dynenv_ros.sim.seeding import checked_seed
from dynenv_ros.soccer.actions import IDLE, Kick, SoccerAction, Turn, Walk
from dynenv_ros.soccer.config import SoccerConfig
from dynenv_ros.soccer.vision import SoccerVision
from dynenv_ros.soccer.world import TEAM_A, TEAM_B, SoccerWorld


class SoccerSession(ActionSession):
    """One world, its perception, and a mailbox of actions per motion period (``session.ActionSession``).

    ``localization=True``: every robot's emulated self-pose estimate is stepped with the vision; after ``initial`` or
    ``step``, ``session.vision.estimate`` (n, 3), ``.covariance`` (n, 3, 3), ``.flipped`` (n,) (field frame, the
    period's last frame; ``soccer/vision.py``)."""

    def __init__(self, config: SoccerConfig, perception: PerceptionParams, seed: int | None = None,
                 missing_action: str = "none", controlled: list[int] | None = None,
                 localization: bool = False) -> None:
        super().__init__(config.n_robots, missing_action, controlled)
        self.config = config
        self.names = config.robot_names
        self.world = SoccerWorld(config, seed=seed)
        self.perception = perception
        self.vision = SoccerVision(self.world, perception, localization=localization)

    # -- episode -----------------------------------------------------------------------------------------------
    reset_options = ("kickoff_team",)

    def new_episode(self, seed: int | None, kickoff_team: int) -> int:
        return self.reset(seed=seed, kickoff_team=kickoff_team)

    def episode_score(self) -> tuple[int, int] | None:
        return (self.world.state.score[1], self.world.state.score[-1])

    def reset(self, seed: int | None = None, kickoff_team: int = TEAM_A) -> int:
        seed = checked_seed(seed)
        if kickoff_team not in (TEAM_A, TEAM_B) or isinstance(kickoff_team, bool):
            raise ValueError(f"kickoff_team must be {TEAM_A} (team A) or {TEAM_B} (team B), got {kickoff_team!r}")
        self._begin_episode()
        self.world.reset(seed=seed, kickoff_team=kickoff_team)
        self.vision.reset()
        self._episode_started()
        return self.world.episode_id

    # -- actions -------------------------------------------------------------------------------------------------
    def submit(self, robot_id: int, episode_id: int, motion_period: int, walk: int, turn: int, kick: int,
               head_yaw_delta: float) -> tuple[bool, str]:
        """Accept one robot's action for the current period, or refuse it with a reason (counted)."""
        return super().submit(robot_id, episode_id, motion_period, walk, turn, kick, head_yaw_delta)

    def check(self, robot_id: int, episode_id: int, motion_period: int, walk: int, turn: int, kick: int,
              head_yaw_delta: float) -> str:
        """Why this action would be refused now ("" if it would be accepted). Reads the state and changes nothing,
        so another thread may screen actions with it (the ROS simulator's action inbox)."""
        return super().check(robot_id, episode_id, motion_period, walk, turn, kick, head_yaw_delta)

    def _check_fields(self, walk, turn, kick, head) -> str:
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

    def _action(self, walk, turn, kick, head) -> SoccerAction:
        return SoccerAction(Walk(walk), Turn(turn), Kick(kick), float(head))

    def idle(self) -> SoccerAction:
        return IDLE

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
        actions = self._period_actions()
        snapshots: list[WorldSnapshot] = []
        ticks: list[int] = []

        def on_frame(k: int) -> None:
            self.vision.frame(k)
            snapshots.append(self.world.snapshot())
            ticks.append(self.world.tick)

        result = self.world.step(actions, on_frame=on_frame)
        perception = self.vision.perceive()
        result.rewards[RewardTerm.OBSERVATION] += self.vision.observation_rewards(perception)
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
