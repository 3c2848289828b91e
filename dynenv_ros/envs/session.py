"""What every scenario's session shares: a world served to asynchronous controllers (ROS nodes, sockets, tests).

Actions arrive one agent at a time and are kept per motion period; a period runs when every controlled agent has
acted, or when told to, and an agent without an action follows the missing-action rule. This module holds the
scenario-neutral part — the mailbox, the envelope checks (agent, episode, period, duplicates), the missing-action
rule, the counters and the records a period produces — so ``soccer_session.SoccerSession`` and
``driving_session.DrivingSession`` only check their own action fields and run their own world. ROS-free.
"""
from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np

from dynenv_ros.sim.ground_truth import WorldSnapshot

MISSING_ACTION_RULES = ("hold", "none")
REJECT_REASONS = ("malformed", "out_of_range", "unknown_robot", "wrong_episode", "late", "early", "duplicate")


@dataclass
class RobotFrame:
    """What one agent perceived at one vision instant, plus its own state and what the GameController told it
    (soccer; a car's frame keeps the soccer-only fields at their defaults)."""
    detections: np.ndarray        # structured DETECTION_DTYPE rows (camera frame)
    head_yaw: float
    fallen: bool
    penalized: bool
    kicking: bool                 # executing a kick
    ball_owner: int               # set-play / kick-off ownership relative to its team: +1 own, -1 opponents, 0 free
    ball_owner_seconds: float     # seconds left of that ownership (0 when free)
    game_seconds_remaining: float
    missed: np.ndarray | None = None   # (m, 2) world positions of objects in view but not detected, if asked for


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
    terminated: bool | None = None   # per agent (driving: a car that can earn nothing more); None: the episode's
    truncated: bool | None = None


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


class ActionSession:
    """The mailbox of one world: subclasses set ``self.world`` (``episode_id``, ``period``, ``tick``) and implement
    ``_check_fields``, ``_action``, ``idle`` and the periods (``initial``, ``step``)."""

    agent_word = "robot"          # how refusals name an agent
    reset_options: tuple[str, ...] = ()     # what a reset may choose (``new_episode``; /sim/reset's options_yaml)

    def __init__(self, n_agents: int, missing_action: str = "none", controlled: Sequence[int] | None = None) -> None:
        if missing_action not in MISSING_ACTION_RULES:
            raise ValueError(f"missing_action must be one of {MISSING_ACTION_RULES}, got {missing_action!r}")
        self.n_agents = n_agents
        self.missing_action = missing_action
        self.controlled = sorted(set(range(n_agents) if controlled is None else controlled))
        for agent in self.controlled:
            if not 0 <= agent < n_agents:
                raise ValueError(f"controlled {self.agent_word} {agent} does not exist "
                                 f"({self.agent_word}s 0..{n_agents - 1})")
        self.pending: dict[int, Any] = {}
        self.last: dict[int, Any] = {}
        self.counts: Counter[str] = Counter()
        self.accepted_per_robot: Counter[int] = Counter()
        self.finished = False
        self._previous_episode, self._previous_final_period = -1, -1
        self.missed_for: int | None = None      # an agent whose misses each frame reports (visualisation)
        self.world: Any = None

    # -- episode -----------------------------------------------------------------------------------------------
    def new_episode(self, seed: int | None, kickoff_team: int) -> int:
        """Start an episode with the reset options a session takes (``kickoff_team``: soccer's)."""
        episode: int = self.reset(seed=seed)
        return episode

    def episode_score(self) -> tuple[int, int] | None:
        """(team A's goals, team B's) of the episode that just ended; None where a game keeps no score."""
        return None

    def report_extra(self) -> dict[str, Any]:
        """What a simulator's exit report adds for this game (``SimGame.report``)."""
        return {}

    def _begin_episode(self) -> None:
        """Before the world resets: policies answer an episode's last frames before they see the next episode,
        so remember which answers to expect."""
        self._previous_episode, self._previous_final_period = self.world.episode_id, self.world.period

    def _episode_started(self) -> None:
        self.pending.clear()
        self.last.clear()
        self.finished = False

    @property
    def episode_id(self) -> int:
        return self.world.episode_id

    @property
    def period(self) -> int:
        """The motion period whose actions are being collected. Period 0 is the observation of the reset state;
        the frames of period p are what the policy sees before acting for period p + 1 (Action.msg)."""
        return self.world.period + 1

    @property
    def tick(self) -> int:
        return self.world.tick

    # -- actions -------------------------------------------------------------------------------------------------
    def submit(self, robot_id: int, episode_id: int, motion_period: int, *fields: Any) -> tuple[bool, str]:
        """Accept one agent's action for the current period, or refuse it with a reason (counted)."""
        reason = self.check(robot_id, episode_id, motion_period, *fields)
        if reason:
            self.counts[refusal_key(reason)] += 1
            return False, reason
        self.pending[robot_id] = self._action(*fields)
        self.counts["accepted"] += 1
        self.accepted_per_robot[robot_id] += 1
        return True, "accepted"

    def check(self, robot_id: int, episode_id: int, motion_period: int, *fields: Any) -> str:
        """Why this action would be refused now ("" if it would be accepted). Reads the state and changes nothing,
        so another thread may screen actions with it (the ROS simulator's action inbox)."""
        return self._check_envelope(robot_id, episode_id, motion_period) or self._check_fields(*fields)

    def _check_envelope(self, robot_id: int, episode_id: int, motion_period: int) -> str:
        word = self.agent_word
        if not 0 <= robot_id < self.n_agents:
            return f"unknown_robot: {word} {robot_id} does not exist"
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
            return f"duplicate: {word} {robot_id} already acted in period {motion_period}"
        return ""

    def _check_fields(self, *fields: Any) -> str:
        raise NotImplementedError

    def _action(self, *fields: Any) -> Any:
        raise NotImplementedError

    def idle(self) -> Any:
        """The action of an agent without one under the 'none' rule."""
        raise NotImplementedError

    def ready(self) -> bool:
        """Every controlled agent has acted for the current period."""
        return all(agent in self.pending for agent in self.controlled)

    def _period_actions(self) -> list[Any]:
        """Every agent's action for the period that runs now; missing ones follow ``missing_action`` (counted for
        controlled agents). Then the mailbox is emptied and these become the last actions."""
        if self.finished:
            raise RuntimeError("the episode has finished; reset first")
        actions = []
        idle = self.idle()
        for agent in range(self.n_agents):
            action = self.pending.get(agent)
            if action is None:
                if agent in self.controlled:
                    self.counts["missing"] += 1
                action = self.last.get(agent, idle) if self.missing_action == "hold" else idle
            actions.append(action)
        self.last = dict(enumerate(actions))
        self.pending.clear()
        return actions


__all__ = ["ActionSession", "MISSING_ACTION_RULES", "REJECT_REASONS", "RobotFrame", "FrameOutput", "RobotFeedback",
           "PeriodOutput", "refusal_key"]
