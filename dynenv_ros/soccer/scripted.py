"""Scripted soccer policies: reproducible opponents and baselines for tests, demos and learning curves.

Every policy reads only the ground-truth ``WorldSnapshot`` (never the world object), so the same code can drive a
robot from the ROS WorldState topic. Policies are stateless except for RandomPolicy's generator: each decision is
a pure function of the snapshot, so a policy can be shared by robots and resumed at any instant.
"""
from __future__ import annotations

import math
from typing import Literal, Protocol, Sequence, runtime_checkable

import numpy as np

from dynenv_ros.core.object_classes import ObjectClass, ObjectStatus
from dynenv_ros.sim.ground_truth import BodyState, WorldSnapshot
from dynenv_ros.soccer.actions import Kick, SoccerAction, Turn, Walk
from dynenv_ros.soccer.config import MotionConfig
from dynenv_ros.soccer.field import FieldGeometry
from dynenv_ros.soccer.robot import FOOT_OFFSET

_MOTION = MotionConfig()
HEAD_MAX_DELTA = _MOTION.head_max_delta       # rad per period: 3 discrete units of 12.5°
KICK_BALL_X = 0.20                            # robot-frame ball x where the foot's stroke meets it squarely
KICK_X_RANGE = (0.15, 0.26)                   # body contact below, end of the stroke (minus a margin) above
KICK_Y_TOLERANCE = 0.04                       # |ball y - foot y|; the foot is 0.09 m wide, the ball 0.1 m
_BUSY = ObjectStatus.FALLEN | ObjectStatus.PENALIZED | ObjectStatus.KICKING


@runtime_checkable
class ScriptedPolicy(Protocol):
    """Anything that picks one robot's action for the next motion period from ground truth."""

    def act(self, snapshot: WorldSnapshot, robot_id: int) -> SoccerAction: ...


# -- small geometry ----------------------------------------------------------------------------------------------
def wrap(angle: float) -> float:
    """Angle in (-π, π]."""
    return math.remainder(angle, math.tau)


def to_robot_frame(robot: BodyState, x: float, y: float) -> tuple[float, float]:
    """Field point → the robot's frame (x forward, y left)."""
    dx, dy = x - robot.x, y - robot.y
    c, s = math.cos(robot.yaw), math.sin(robot.yaw)
    return c * dx + s * dy, -s * dx + c * dy


def find_robot(snapshot: WorldSnapshot, robot_id: int) -> BodyState:
    for o in snapshot.objects:
        if o.class_id == ObjectClass.ROBOT and o.id == robot_id:
            return o
    raise KeyError(f"no robot with id {robot_id} in the snapshot")


def find_ball(snapshot: WorldSnapshot) -> BodyState:
    balls = snapshot.of_class(ObjectClass.BALL)
    if not balls:
        raise KeyError("no ball in the snapshot")
    return balls[0]


def head_toward(robot: BodyState, x: float, y: float, max_delta: float = HEAD_MAX_DELTA) -> float:
    """Head turn for one period that brings the gaze toward a field point, as far as one period allows."""
    fx, fy = to_robot_frame(robot, x, y)
    return max(-max_delta, min(max_delta, wrap(math.atan2(fy, fx) - robot.head_yaw)))


def turn_toward(error: float, deadband: float = 0.5 * _MOTION.turn_step) -> Turn:
    """Turn that reduces a heading error (rad, positive = target is to the left)."""
    if error > deadband:
        return Turn.LEFT
    if error < -deadband:
        return Turn.RIGHT
    return Turn.NONE


def step_toward(fx: float, fy: float, deadband: float = 0.02) -> Walk:
    """Walk along the robot-frame axis that covers most of the way to a point (fx forward, fy left)."""
    if max(abs(fx), abs(fy)) < deadband:
        return Walk.NONE
    if abs(fx) >= abs(fy):
        return Walk.FORWARD if fx > 0 else Walk.BACKWARD
    return Walk.LEFT if fy > 0 else Walk.RIGHT


def kick_foot_for(fx: float, fy: float) -> Kick:
    """The foot the ball (robot frame) lies squarely in front of, or NONE."""
    if not KICK_X_RANGE[0] < fx < KICK_X_RANGE[1]:
        return Kick.NONE
    for foot, side in ((Kick.LEFT_FOOT, FOOT_OFFSET), (Kick.RIGHT_FOOT, -FOOT_OFFSET)):
        if abs(fy - side) < KICK_Y_TOLERANCE:
            return foot
    return Kick.NONE


def _can_act(robot: BodyState) -> bool:
    return not (robot.status & _BUSY)


# -- policies ----------------------------------------------------------------------------------------------------
class RandomPolicy:
    """Uniform over walk, turn, kick and head: the weakest baseline, and a fuzzer for the world and the nodes."""

    def __init__(self, rng: np.random.Generator, head_mode: Literal["discrete", "continuous"] = "discrete",
                 head_step: float = _MOTION.head_step, head_units: int = _MOTION.head_units) -> None:
        if head_mode not in ("discrete", "continuous"):
            raise ValueError(f"head_mode must be 'discrete' or 'continuous', got {head_mode!r}")
        self.rng = rng
        self.head_mode = head_mode
        self.head_step = head_step
        self.head_units = head_units

    def act(self, snapshot: WorldSnapshot, robot_id: int) -> SoccerAction:
        walk = Walk(int(self.rng.integers(len(Walk))))
        turn = Turn(int(self.rng.integers(len(Turn))))
        kick = Kick(int(self.rng.integers(len(Kick))))
        if self.head_mode == "discrete":   # the same deltas a discrete head index can express
            head = (int(self.rng.integers(2 * self.head_units + 1)) - self.head_units) * self.head_step
        else:
            limit = self.head_step * self.head_units
            head = float(self.rng.uniform(-limit, limit))
        return SoccerAction(walk, turn, kick, head)


class ChaserPolicy:
    """Walk behind the ball on the opponent-goal line, face the goal, line the ball up with a foot and kick.

    Stateless: the phase (circle round, approach, line up, kick) is read from the geometry each period, so a ball
    that rolls away or a robot that was pushed simply re-plans. Getting behind the ball goes round it on a circle
    (a waypoint a fixed angle further round), which never crosses the ball and has no zone edge to dither on.
    """

    def __init__(self, field: FieldGeometry | None = None, head_max_delta: float = HEAD_MAX_DELTA,
                 behind: float = 0.35, orbit_radius: float = 0.45, free_kick_distance: float = 0.9,
                 aim_depth: float = 0.3, eager_kick_tolerance: float | None = None) -> None:
        self.field = field or FieldGeometry()
        # rad: kick whenever the ball lies squarely in front of a foot and the robot faces the aim within this,
        # whatever the phase (None: only at the end of the line-up). A teacher whose kicks depend on what the
        # robot's camera shows (the ball at its feet) rather than on a 0.12 rad alignment it cannot measure.
        self.eager_kick_tolerance = eager_kick_tolerance
        self.head_max_delta = head_max_delta
        self.aim_depth = aim_depth                    # m behind the goal line: a ball on the line still goes in
        self.behind = behind                          # m behind the ball where the final approach starts
        self.orbit_radius = orbit_radius              # m kept from the ball while going round it
        self.free_kick_distance = free_kick_distance  # m kept from the ball while the opponents own it

    def act(self, snapshot: WorldSnapshot, robot_id: int) -> SoccerAction:
        me, ball = find_robot(snapshot, robot_id), find_ball(snapshot)
        head = head_toward(me, ball.x, ball.y, self.head_max_delta)
        if not _can_act(me) or me.team == 0:
            return SoccerAction(head_yaw_delta=head)
        goal_x = me.team * (self.field.half_length + self.aim_depth)
        ux, uy = goal_x - ball.x, -ball.y
        norm = math.hypot(ux, uy) or 1.0
        ux, uy = ux / norm, uy / norm                  # unit vector ball → aim point inside the opponent goal
        aim = math.atan2(uy, ux)
        rx, ry = me.x - ball.x, me.y - ball.y
        along = rx * ux + ry * uy                      # < 0: the robot is on the own-goal side of the ball
        lateral = -rx * uy + ry * ux                   # > 0: left of the ball → goal line
        if snapshot.ball_owner_team == -me.team:       # touching it now would be a penalty: wait off the ball
            tx, ty = self._round_the_ball(ball, ux, uy, along, lateral, self.free_kick_distance,
                                          self.free_kick_distance)
            return self._go_to(me, tx, ty, aim, head)
        if self.eager_kick_tolerance is not None and abs(wrap(aim - me.yaw)) < self.eager_kick_tolerance:
            foot = kick_foot_for(*to_robot_frame(me, ball.x, ball.y))
            if foot != Kick.NONE:
                return SoccerAction(Walk.NONE, Turn.NONE, foot, head)
        if -(self.behind + 0.15) < along < -0.1 and abs(lateral) < 0.12:
            return self._line_up(me, ball, aim, head)
        tx, ty = self._round_the_ball(ball, ux, uy, along, lateral, self.behind, self.orbit_radius)
        return self._go_to(me, tx, ty, aim, head)

    @staticmethod
    def _round_the_ball(ball: BodyState, ux: float, uy: float, along: float, lateral: float, behind: float,
                        radius: float) -> tuple[float, float]:
        """Next waypoint toward the spot ``behind`` the ball, going round it at ``radius`` when not behind yet."""
        phi = math.atan2(lateral, -along)              # 0 straight behind the ball, ±π straight in front
        if abs(phi) < 0.5:
            return ball.x - ux * behind, ball.y - uy * behind
        phi -= math.copysign(0.6, phi)                 # a bit further round, toward the back
        back, left = -math.cos(phi) * radius, math.sin(phi) * radius
        return ball.x + ux * back - uy * left, ball.y + uy * back + ux * left

    def _go_to(self, me: BodyState, tx: float, ty: float, final_yaw: float, head: float) -> SoccerAction:
        """Face the way and walk forward when far; near the point, face ``final_yaw`` and step sideways/back."""
        fx, fy = to_robot_frame(me, tx, ty)
        dist = math.hypot(fx, fy)
        if dist > 0.5:
            bearing = math.atan2(fy, fx)
            walk = Walk.FORWARD if abs(bearing) < 0.6 else Walk.NONE
            return SoccerAction(walk, turn_toward(bearing), Kick.NONE, head)
        return SoccerAction(step_toward(fx, fy), turn_toward(wrap(final_yaw - me.yaw)), Kick.NONE, head)

    def _line_up(self, me: BodyState, ball: BodyState, aim: float, head: float) -> SoccerAction:
        """Close behind the ball: square up to the goal, bring the ball in front of the nearer foot, kick."""
        yaw_error = wrap(aim - me.yaw)
        fx, fy = to_robot_frame(me, ball.x, ball.y)
        side = FOOT_OFFSET if fy >= 0 else -FOOT_OFFSET
        if abs(yaw_error) < 0.12:
            foot = kick_foot_for(fx, fy)
            if foot != Kick.NONE:
                return SoccerAction(Walk.NONE, Turn.NONE, foot, head)
        walk = step_toward(fx - KICK_BALL_X, fy - side, deadband=0.015)
        if walk == Walk.FORWARD and fx - KICK_BALL_X < 0.03:
            walk = Walk.NONE                           # a full step would bump the ball away
        return SoccerAction(walk, turn_toward(yaw_error), Kick.NONE, head)


class GoalkeeperPolicy:
    """Guard the own goal: stay just in front of the goal line at the ball's y (within the goal mouth), face the
    field, and clear the ball when it comes close in front."""

    def __init__(self, field: FieldGeometry | None = None, head_max_delta: float = HEAD_MAX_DELTA,
                 line_offset: float = 0.3, reach: float = 0.6) -> None:
        self.field = field or FieldGeometry()
        self.head_max_delta = head_max_delta
        self.line_offset = line_offset   # m in front of the goal line
        self.reach = reach               # m from the guard line within which it steps out to clear the ball

    def act(self, snapshot: WorldSnapshot, robot_id: int) -> SoccerAction:
        me, ball = find_robot(snapshot, robot_id), find_ball(snapshot)
        head = head_toward(me, ball.x, ball.y, self.head_max_delta)
        if not _can_act(me) or me.team == 0:
            return SoccerAction(head_yaw_delta=head)
        f = self.field
        goal_line = -me.team * f.half_length
        guard_x = goal_line + me.team * self.line_offset
        field_yaw = 0.0 if me.team > 0 else math.pi
        fx, fy = to_robot_frame(me, ball.x, ball.y)
        foot = kick_foot_for(fx, fy)
        if foot != Kick.NONE and abs(wrap(field_yaw - me.yaw)) < 0.5:
            return SoccerAction(Walk.NONE, Turn.NONE, foot, head)
        # Ball in front and within reach of the guard line, inside the penalty area: step out to it and clear.
        depth = me.team * (ball.x - guard_x)          # how far the ball is in front of the guard line
        area_half = f.penalty_area_width / 2
        max_depth = f.penalty_area_length - self.line_offset - 0.3
        if 0.1 < depth < self.reach and abs(ball.y) < area_half - 0.3:
            side = FOOT_OFFSET if fy >= 0 else -FOOT_OFFSET
            tx = ball.x - me.team * KICK_BALL_X
            ty = ball.y - me.team * side               # robot-frame +y is field +y for team A, -y for team B
            if me.team * (tx - guard_x) > max_depth:
                tx = guard_x + me.team * max_depth
        else:
            limit = f.goal_width / 2 - 0.1
            tx, ty = guard_x, max(-limit, min(limit, ball.y))
        gx, gy = to_robot_frame(me, tx, ty)
        walk = step_toward(gx, gy, deadband=0.02)
        return SoccerAction(walk, turn_toward(wrap(field_yaw - me.yaw)), Kick.NONE, head)


# -- teams -------------------------------------------------------------------------------------------------------
PolicyKind = Literal["chaser", "eager_chaser", "random", "keeper_and_chasers"]
# The kinds a scripted *team* plays as an opponent or baseline ('random' aside), and the one "scripted" means in
# dynenv-eval and in training against the scripted team.
SCRIPTED_KINDS = ("chaser", "eager_chaser", "keeper_and_chasers")
DEFAULT_SCRIPTED = "keeper_and_chasers"
EAGER_KICK_TOLERANCE = 1.2     # rad; 18 : 10 against keeper_and_chasers in 30 games (chaser: 17 : 12), docs/results.md


def team_policies(n_per_team: int, kind: PolicyKind = "chaser", rng: np.random.Generator | None = None, *,
                  field: FieldGeometry | None = None, head_mode: Literal["discrete", "continuous"] = "discrete",
                  motion: MotionConfig | None = None) -> list[ScriptedPolicy]:
    """One policy per robot id (team A's slots, then team B's), all of one kind.

    'random' gives each robot its own generator spawned from ``rng`` (a fresh unseeded one if None), so robots
    are independent yet the whole team is reproducible from one seed. 'keeper_and_chasers' puts a goalkeeper in
    slot 0 of each team and chasers elsewhere; a team of one gets a chaser, since a lone keeper never plays.
    """
    if isinstance(n_per_team, bool) or not isinstance(n_per_team, int) or n_per_team < 1:
        raise ValueError(f"n_per_team must be a positive integer, got {n_per_team!r}")
    m = motion or MotionConfig()
    n = 2 * n_per_team
    if kind == "chaser":
        return [ChaserPolicy(field, m.head_max_delta) for _ in range(n)]
    if kind == "eager_chaser":
        return [ChaserPolicy(field, m.head_max_delta, eager_kick_tolerance=EAGER_KICK_TOLERANCE) for _ in range(n)]
    if kind == "random":
        rngs = (rng if rng is not None else np.random.default_rng()).spawn(n)
        return [RandomPolicy(r, head_mode, m.head_step, m.head_units) for r in rngs]
    if kind == "keeper_and_chasers":
        return [GoalkeeperPolicy(field, m.head_max_delta) if i % n_per_team == 0 and n_per_team > 1
                else ChaserPolicy(field, m.head_max_delta) for i in range(n)]
    raise ValueError(f"kind must be 'chaser', 'eager_chaser', 'random' or 'keeper_and_chasers', got {kind!r}")


def act_all(policies: Sequence[ScriptedPolicy], snapshot: WorldSnapshot) -> list[SoccerAction]:
    """Every robot's action for the next period; policy i drives robot id i."""
    return [policy.act(snapshot, i) for i, policy in enumerate(policies)]


__all__ = ["ScriptedPolicy", "RandomPolicy", "ChaserPolicy", "GoalkeeperPolicy", "team_policies", "act_all",
           "wrap", "to_robot_frame", "find_robot", "find_ball", "head_toward", "kick_foot_for", "HEAD_MAX_DELTA",
           "SCRIPTED_KINDS", "DEFAULT_SCRIPTED"]
