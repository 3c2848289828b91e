"""A walking robot: its bodies in the physics world, its high-level motions, and its rule state.

The body is a dynamic circle driven by a kinematic control body (``sim.physics.Drive``). A kick adds a kinematic
foot that really strikes forward and back, so the ball moves only if the foot meets it.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import pymunk

from dynenv_ros.sim.physics import Drive
from dynenv_ros.soccer.actions import Kick, SoccerAction, Turn, Walk
from dynenv_ros.soccer.config import SoccerConfig

BODY_RADIUS = 0.1          # m: top-down hull of a standing NAO
FOOT_OFFSET = 0.05         # m: each foot's centre to the side of the body axis
FOOT_LENGTH = 0.16
FOOT_WIDTH = 0.09


class CollisionType:
    """pymunk collision types of the soccer world."""
    ROBOT = 1
    BALL = 2
    GOALPOST = 3
    KICK_FOOT = 4
    BALL_OUT = 5


class Category:
    """Shape-filter category bits: who may touch whom."""
    ROBOT = 1
    BALL = 2
    GOALPOST = 4
    SENSOR = 8


@dataclass
class KickStroke:
    """A kick in progress: periods left and the foot body while it strikes."""
    foot: Kick
    periods_left: int
    foot_body: pymunk.Body | None = None
    foot_shape: pymunk.Shape | None = None


@dataclass
class RobotRules:
    """What the referee tracks for one robot."""
    fallen: bool = False
    fall_timer: float = 0.0
    fall_count: int = 0
    penalized: bool = False
    penalty_remaining: float = 0.0
    contact_ticks: int = 0
    entered_own_area_tick: int | None = None
    last_ball_distance: float | None = None
    approach_candidate: float = 0.0
    penalty_reasons: list[str] = field(default_factory=list)
    absent: bool = False        # out of play for the whole episode (an attack start without defenders); penalized too


class Robot:
    def __init__(self, index: int, team: int, slot: int, config: SoccerConfig) -> None:
        self.index = index
        self.team = team          # +1 team A, -1 team B
        self.slot = slot          # number within its team
        self.config = config
        mass = config.robot_mass
        self.body = pymunk.Body(mass, pymunk.moment_for_circle(mass, 0.0, BODY_RADIUS))
        self.shape = pymunk.Circle(self.body, BODY_RADIUS)
        self.shape.elasticity = 0.3
        self.shape.friction = 0.8
        self.shape.collision_type = CollisionType.ROBOT
        self.shape.filter = pymunk.ShapeFilter(group=index + 1, categories=Category.ROBOT,
                                               mask=Category.ROBOT | Category.BALL | Category.GOALPOST)
        self.drive: Drive | None = None
        self.head_yaw = 0.0
        self.head_start = 0.0
        self.head_delta = 0.0
        self.kick: KickStroke | None = None
        self.rules = RobotRules()
        self.in_space = False
        self.pushing: set[int] = set()    # indices of robots this one is walking into

    # -- placement -------------------------------------------------------------------------------------------
    def add_to(self, space: pymunk.Space) -> None:
        space.add(self.body, self.shape)
        if self.drive is None:
            m = self.config.motion
            self.drive = Drive.attach(space, self.body, m.drive_max_force, m.drive_max_torque)
        else:
            space.add(self.drive.control, self.drive.pivot, self.drive.gear)
        self.in_space = True

    def remove_from(self, space: pymunk.Space) -> None:
        self.end_kick(space)
        if self.in_space:
            assert self.drive is not None
            space.remove(self.body, self.shape, self.drive.control, self.drive.pivot, self.drive.gear)
        self.in_space = False
        self.pushing.clear()

    def place(self, x: float, y: float, yaw: float) -> None:
        if self.drive is not None:
            self.drive.place(x, y, yaw)
        else:
            self.body.position = (x, y)
            self.body.angle = yaw

    # -- state -------------------------------------------------------------------------------------------------
    @property
    def x(self) -> float:
        return self.body.position.x

    @property
    def y(self) -> float:
        return self.body.position.y

    @property
    def yaw(self) -> float:
        return math.remainder(self.body.angle, math.tau)

    @property
    def can_act(self) -> bool:
        return not (self.rules.fallen or self.rules.penalized or self.kick is not None)

    def commanded_velocity(self) -> tuple[float, float]:
        if self.drive is None or not self.in_space:
            return (0.0, 0.0)
        v = self.drive.control.velocity
        return (v.x, v.y)

    # -- motion ------------------------------------------------------------------------------------------------
    def begin_head_turn(self, delta: float) -> None:
        self.head_start = self.head_yaw
        self.head_delta = delta

    def head_at(self, fraction: float) -> float:
        """Head yaw a fraction of the way through the period (a constant-rate turn, clamped at the limit)."""
        limit = self.config.motion.head_limit
        return min(limit, max(-limit, self.head_start + self.head_delta * fraction))

    def walk(self, action: SoccerAction, period_seconds: float) -> None:
        """Hold the walk and turn velocities that cover the configured step in one period."""
        assert self.drive is not None
        m = self.config.motion
        forward = {Walk.FORWARD: m.forward_step, Walk.BACKWARD: -m.backward_step}.get(action.walk, 0.0)
        left = {Walk.LEFT: m.side_step, Walk.RIGHT: -m.side_step}.get(action.walk, 0.0)
        yaw_rate = {Turn.LEFT: m.turn_step, Turn.RIGHT: -m.turn_step}.get(action.turn, 0.0) / period_seconds
        # Velocity along the heading at mid-period, so walking while turning ends near the arc it should follow.
        heading = self.body.angle + 0.5 * yaw_rate * period_seconds
        c, s = math.cos(heading), math.sin(heading)
        self.drive.command((c * forward - s * left) / period_seconds, (s * forward + c * left) / period_seconds,
                           yaw_rate)

    def stand(self) -> None:
        if self.drive is not None and self.in_space:
            self.drive.command(0.0, 0.0, 0.0)

    def start_kick(self, foot: Kick) -> None:
        self.stand()
        self.kick = KickStroke(foot, self.config.kick.periods)

    def strike(self, space: pymunk.Space, direction: float) -> None:
        """Put the kicking foot into the world (first call) and move it forward (+1), back (-1)."""
        assert self.kick is not None
        speed = self.config.kick.strike_speed * direction
        c, s = math.cos(self.body.angle), math.sin(self.body.angle)
        if self.kick.foot_body is None:
            side = FOOT_OFFSET if self.kick.foot == Kick.LEFT_FOOT else -FOOT_OFFSET
            foot = pymunk.Body(body_type=pymunk.Body.KINEMATIC)
            foot.position = self.body.local_to_world((0.0, side))
            foot.angle = self.body.angle
            half_l, half_w = FOOT_LENGTH / 2, FOOT_WIDTH / 2
            shape = pymunk.Poly(foot, [(-half_l, -half_w), (half_l, -half_w), (half_l, half_w), (-half_l, half_w)])
            shape.elasticity = 1.0
            shape.friction = 0.5
            shape.collision_type = CollisionType.KICK_FOOT
            shape.filter = pymunk.ShapeFilter(group=self.index + 1, categories=Category.ROBOT,
                                              mask=Category.ROBOT | Category.BALL)
            space.add(foot, shape)
            self.kick.foot_body, self.kick.foot_shape = foot, shape
        self.kick.foot_body.velocity = (c * speed, s * speed)

    def withdraw_foot(self, space: pymunk.Space) -> None:
        if self.kick is not None and self.kick.foot_body is not None:
            space.remove(self.kick.foot_body, self.kick.foot_shape)
            self.kick.foot_body = self.kick.foot_shape = None

    def end_kick(self, space: pymunk.Space) -> None:
        self.withdraw_foot(space)
        self.kick = None
