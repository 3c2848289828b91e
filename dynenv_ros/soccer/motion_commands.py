"""A discrete soccer action as a walk engine's commands, and back (issue 41; docs/deploy.md, "Walk, kick and head
commands"). ROS-free: numbers in, numbers out.

A robot stack's walk engine takes a velocity target (``geometry_msgs/Twist``: x forward, y left, m/s; z
counter-clockwise, rad/s; REP 103, the robot's ``base_link``), its kick engine a request naming the foot, its head a
joint command. One discrete action of the motion layer (soccer/actions.py) is one motion period of fixed steps
(docs/soccer.md, "Actions"), so the twist is the step divided by the period:

| action | twist (default steps, 0.5 s period) |
|---|---|
| walk FORWARD | linear.x = forward_step / period = 0.055 / 0.5 = +0.11 m/s |
| walk BACKWARD | linear.x = −backward_step / period = −0.072 m/s |
| walk LEFT / RIGHT | linear.y = ±side_step / period = ±0.072 m/s |
| turn LEFT / RIGHT | angular.z = ±turn_step / period = ±0.2 rad/s |
| kick (walk and turn NONE) | zero twist and a kick request for the foot |
| head_yaw_delta δ | head yaw rate δ / period (rad/s), target = the head's yaw + δ |

A kick starts only when the robot neither walks nor turns (docs/soccer.md); an action with a kick and a walk or
turn walks, so no kick request goes out for it.

Back (``action_of``: the motion emulator, a twist from any stack): each axis is quantised to the nearest of none and
its step speed — a speed of at least half the step speed moves; of the two walk axes the one further along its step
wins (a diagonal target walks along its larger component); a pending kick request kicks (the walk engine stands for
the kick engine) and clears walking and turning. The head turns by rate × period, within the per-period bound.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from dynenv_ros.soccer.actions import Kick, Turn, Walk
from dynenv_ros.soccer.config import MotionConfig

# A twist component this far along its step speed (or more) is a step; less is none.
STEP_THRESHOLD = 0.5
# Bounds of what a walk engine command may hold before it is refused (10x the fastest step speed: no NAO walks 1 m/s).
MAX_SPEED = 1.0       # m/s
MAX_TURN_RATE = 5.0   # rad/s


@dataclass(frozen=True)
class StepSpeeds:
    """The motion layer's steps as speeds: m/s forward, backward, sideways; rad/s turning; the period (s)."""
    forward: float
    backward: float
    side: float
    turn: float
    period_s: float

    @classmethod
    def of(cls, motion: MotionConfig, period_s: float) -> "StepSpeeds":
        if not (math.isfinite(period_s) and period_s > 0):
            raise ValueError(f"the motion period must be a positive number of seconds, got {period_s}")
        return cls(motion.forward_step / period_s, motion.backward_step / period_s, motion.side_step / period_s,
                   motion.turn_step / period_s, period_s)


@dataclass(frozen=True)
class MotionCommand:
    """What one action asks of the robot's engines: the walk target, a kick request, the head's rate."""
    vx: float = 0.0          # m/s, + forward
    vy: float = 0.0          # m/s, + left
    wz: float = 0.0          # rad/s, + counter-clockwise
    kick: int = int(Kick.NONE)   # Kick.LEFT_FOOT / RIGHT_FOOT: request a kick with that foot
    head_rate: float = 0.0   # rad/s over the coming period, + left


def command_of(walk: int, turn: int, kick: int, head_yaw_delta: float, speeds: StepSpeeds) -> MotionCommand:
    """The engines' commands for one discrete action (module docstring's table)."""
    walk, turn, kick = Walk(int(walk)), Turn(int(turn)), Kick(int(kick))
    if not math.isfinite(head_yaw_delta):
        raise ValueError(f"head_yaw_delta must be finite, got {head_yaw_delta}")
    vx = {Walk.FORWARD: speeds.forward, Walk.BACKWARD: -speeds.backward}.get(walk, 0.0)
    vy = {Walk.LEFT: speeds.side, Walk.RIGHT: -speeds.side}.get(walk, 0.0)
    wz = {Turn.LEFT: speeds.turn, Turn.RIGHT: -speeds.turn}.get(turn, 0.0)
    moves = walk != Walk.NONE or turn != Turn.NONE
    return MotionCommand(vx, vy, wz, int(Kick.NONE) if moves else int(kick), head_yaw_delta / speeds.period_s)


def command_problem(vx: float, vy: float, wz: float) -> str:
    """Why a walk target cannot be a command ('' if it can): not finite, or beyond what any robot walks."""
    if not all(math.isfinite(v) for v in (vx, vy, wz)):
        return f"walk target ({vx}, {vy}, {wz}) is not finite"
    if math.hypot(vx, vy) > MAX_SPEED or abs(wz) > MAX_TURN_RATE:
        return (f"walk target ({vx:.3g} m/s, {vy:.3g} m/s, {wz:.3g} rad/s) is beyond {MAX_SPEED} m/s or "
                f"{MAX_TURN_RATE} rad/s")
    return ""


def head_problem(rate: float) -> str:
    """Why a head rate cannot be a command ('' if it can)."""
    if not math.isfinite(rate):
        return f"head rate {rate} is not finite"
    if abs(rate) > MAX_TURN_RATE * 10:
        return f"head rate {rate:.3g} rad/s is beyond {MAX_TURN_RATE * 10} rad/s"
    return ""


def _steps(value: float, plus: float, minus: float) -> tuple[int, float]:
    """(−1, 0 or +1, how far along its step speed) of one axis."""
    step = plus if value >= 0 else minus
    along = abs(value) / step if step > 0 else 0.0
    return (0 if along < STEP_THRESHOLD else (1 if value > 0 else -1)), along


def action_of(command: MotionCommand, speeds: StepSpeeds, head_max_delta: float) -> tuple[int, int, int, float]:
    """(walk, turn, kick, head_yaw_delta) that carries out ``command`` for one period (module docstring)."""
    problem = command_problem(command.vx, command.vy, command.wz) or head_problem(command.head_rate)
    if problem:
        raise ValueError(problem)
    head = max(-head_max_delta, min(head_max_delta, command.head_rate * speeds.period_s))
    if command.kick != Kick.NONE:
        return int(Walk.NONE), int(Turn.NONE), int(Kick(command.kick)), head
    x, along_x = _steps(command.vx, speeds.forward, speeds.backward)
    y, along_y = _steps(command.vy, speeds.side, speeds.side)
    if x and (not y or along_x >= along_y):
        walk = Walk.FORWARD if x > 0 else Walk.BACKWARD
    elif y:
        walk = Walk.LEFT if y > 0 else Walk.RIGHT
    else:
        walk = Walk.NONE
    z, _ = _steps(command.wz, speeds.turn, speeds.turn)
    turn = Turn.LEFT if z > 0 else Turn.RIGHT if z < 0 else Turn.NONE
    return int(walk), int(turn), int(Kick.NONE), head


__all__ = ["MAX_SPEED", "MAX_TURN_RATE", "STEP_THRESHOLD", "MotionCommand", "StepSpeeds", "action_of", "command_of",
           "command_problem", "head_problem"]
