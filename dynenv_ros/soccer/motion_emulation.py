"""A robot's walk engine, kick engine and head as the motion emulator runs them over the simulator (issue 41;
docs/deploy.md, "The motion emulator"). ROS-free: numbers in, one action per motion period out; times in ns.

The engines act on the newest command: the newest walk target (until it is ``twist_max_age`` old: a walk engine
whose commander went quiet stops), a kick request once, and the head command of the period. The simulator runs
discrete periods, so ``EngineLatch`` turns them into one action per period:

- The simulator ends a period (``period_ended``: its feedback names the episode, the period and the stamp of the
  period's last frame). The action for the next period is due.
- It is sent when a head command answering that frame arrives (stamped no earlier than the frame's stamp less
  ``tolerance_ns``; the policy node sends the head command last, after the kick and the twist), or when
  ``timeout_ns`` has passed without one (the engines keep the newest walk target; the head holds still); the
  simulator's initial period (period 0) at once with the engines' current commands (once anyone commands them): its
  frames repeat one instant, which no camera does, so a team's stack (and the policy node's frame grid) has nothing
  to answer.
- The action: a pending kick request kicks (the walk engine stands for the kick engine), else the walk target
  quantised to the motion layer's steps; the head turns by the head command's rate × period
  (``motion_commands.action_of``).
"""
from __future__ import annotations

from dataclasses import dataclass

from dynenv_ros.soccer.actions import Kick
from dynenv_ros.soccer.motion_commands import MotionCommand, StepSpeeds, action_of, command_problem, head_problem


@dataclass(frozen=True)
class Due:
    """The action for ``period`` of ``episode``, and why it went out (``answered``, ``timeout``, ``initial``)."""
    episode: int
    period: int
    stamp_ns: int
    action: tuple[int, int, int, float]
    why: str


class EngineLatch:
    """One robot's newest commands and the period waiting for its action (module docstring)."""

    def __init__(self, speeds: StepSpeeds, head_max_delta: float, tolerance_ns: int, timeout_ns: int,
                 twist_max_age_ns: int) -> None:
        self.speeds, self.head_max_delta = speeds, head_max_delta
        self.tolerance_ns, self.timeout_ns, self.twist_max_age_ns = tolerance_ns, timeout_ns, twist_max_age_ns
        self.twist: tuple[float, float, float] = (0.0, 0.0, 0.0)
        self.twist_at: int | None = None
        self.kick = int(Kick.NONE)
        self.head: tuple[int, float] | None = None          # (stamp ns, rate rad/s) not used yet
        self.waiting: tuple[int, int, int, int] | None = None   # (episode, period, frame stamp, since ns)

    def walk_target(self, vx: float, vy: float, wz: float, now_ns: int) -> str:
        """File a walk target; the reason it is refused ('' when filed)."""
        problem = command_problem(vx, vy, wz)
        if not problem:
            self.twist, self.twist_at = (vx, vy, wz), now_ns
        return problem

    def kick_request(self, use_left_foot: bool) -> None:
        self.kick = int(Kick.LEFT_FOOT if use_left_foot else Kick.RIGHT_FOOT)

    def head_command(self, stamp_ns: int, rate: float) -> str:
        """File a head command (its stamp: the frame it answers); the reason it is refused ('' when filed)."""
        problem = head_problem(rate)
        if not problem:
            self.head = (stamp_ns, rate)
        return problem

    def period_ended(self, episode: int, period: int, stamp_ns: int, now_ns: int) -> None:
        """The simulator finished ``period``: the next one's action is due (a later end replaces an unanswered one)."""
        self.waiting = (episode, period, stamp_ns, now_ns)

    def due(self, now_ns: int, commander: bool = True) -> Due | None:
        """The action due now, if any; ``commander``: whether anyone publishes commands yet (no timeout before)."""
        if self.waiting is None:
            return None
        episode, period, stamp, since = self.waiting
        answered = self.head is not None and self.head[0] >= stamp - self.tolerance_ns
        if period == 0 and commander:
            why = "initial"
        elif answered:
            why = "answered"
        elif commander and now_ns - since >= self.timeout_ns:
            why = "timeout"
        else:
            return None
        rate = self.head[1] if answered and self.head is not None else 0.0
        fresh = self.twist_at is not None and now_ns - self.twist_at <= self.twist_max_age_ns
        vx, vy, wz = self.twist if fresh else (0.0, 0.0, 0.0)
        action = action_of(MotionCommand(vx, vy, wz, self.kick, rate), self.speeds, self.head_max_delta)
        self.kick, self.waiting = int(Kick.NONE), None
        if answered:
            self.head = None
        return Due(episode, period + 1, stamp, action, why)


__all__ = ["Due", "EngineLatch"]
