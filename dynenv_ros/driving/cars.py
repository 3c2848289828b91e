"""Cars: their types, their actions and the vehicle model on a pymunk body.

Vehicle model (docs/driving.md): the original's heading–velocity model made continuous and physical. A car has a
signed speed u along its heading. Once per motion period the action changes u (traction, braking and rolling
resistance with the original's figures) and sets a yaw rate ω; the car then holds velocity u along its heading
(at mid-period) and yaw rate ω through a kinematic control body joined to it by a pivot and a gear joint with
capped force (``sim.physics.Drive``): the joint force is the tyres' grip, so the car follows its command exactly
when nothing is in the way, and contacts push it like any body. |ω| is bounded by the steering limit and by
|u| / min_turn_radius (a car cannot turn on the spot, as the original's could). Once crashed or finished the
command is zero velocity with the joint force capped at the original's high friction, i.e. a constant
deceleration to a stop, solved in C. Per tick the only Python work is ``Space.step``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Mapping

import numpy as np
import pymunk

from dynenv_ros.driving.config import CarConfig
from dynenv_ros.sim.physics import Drive

ACCELERATION_CHOICES = 3            # discrete index 0 reverse, 1 brake, 2 gas (the original's acc = index − 1)
STEERING_CHOICES = 3                # discrete index 0 right, 1 straight, 2 left (+yaw, counter-clockwise)
_TOLERANCE = 1e-6                   # float32 round-off accepted at a bound (then clamped)


class CollisionType:
    """pymunk collision types of the driving world."""
    CAR = 1
    PEDESTRIAN = 2
    OBSTACLE = 3
    BUILDING = 4
    WALL = 5


class Category:
    """Shape-filter category bits: cars touch everything; pedestrians only cars (DynEnv ignores pedestrian contacts
    with each other and with obstacles)."""
    CAR = 1
    PEDESTRIAN = 2
    STATIC = 4


@dataclass(frozen=True)
class CarType:
    index: int
    mass: float
    half_width: float
    half_length: float
    power: float


def car_types(config: CarConfig) -> tuple[CarType, ...]:
    return tuple(CarType(i, m, w, h, p) for i, (m, w, h, p) in
                 enumerate(zip(config.masses, config.half_widths, config.half_lengths, config.powers)))


# -- actions -------------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class DrivingAction:
    """One car's command for one period, as the driving fields of dynenv_msgs/Action."""
    throttle: float = 0.0           # [-1, 1], negative: reverse
    brake: float = 0.0              # [0, 1]
    steering: float = 0.0           # yaw rate, rad/s, + left (counter-clockwise)


BRAKE = DrivingAction(brake=1.0)


def discrete_action(acceleration: int, steering: int, max_yaw_rate: float) -> DrivingAction:
    """The original's MultiDiscrete([3, 3]): acc = index − 1 (−1 reverse, 0 **brake**, +1 gas); steering index − 1
    times the steering limit (±2° per 100 ms), + left."""
    throttle = float(acceleration - 1) if acceleration != 1 else 0.0
    return DrivingAction(throttle=throttle, brake=1.0 if acceleration == 1 else 0.0,
                         steering=(steering - 1) * max_yaw_rate)


def normalised_commands(commands: Any, max_yaw_rate: float) -> np.ndarray:
    """[throttle, brake, steering rad/s] rows as the normalised [throttle, brake, steering / limit] a learner stores
    a continuous action in (``driving.agent_actions.commands`` turns them back)."""
    return np.asarray(commands, np.float64) / np.array([1.0, 1.0, max_yaw_rate])


def _index(car: str, name: str, value: Any, choices: int) -> int:
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)) and not (
            isinstance(value, (float, np.floating)) and float(value).is_integer()):
        raise ValueError(f"{car}: action field '{name}' must be an integer index in 0..{choices - 1}, got {value!r}")
    if not 0 <= int(value) < choices:
        raise ValueError(f"{car}: action field '{name}'={int(value)} is out of range 0..{choices - 1}")
    return int(value)


def _bounded(car: str, name: str, value: Any, low: float, high: float) -> float:
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise ValueError(f"{car}: action field '{name}' must be a number, got {value!r}")
    v = float(value)
    if not math.isfinite(v):
        raise ValueError(f"{car}: action field '{name}' must be finite, got {v}")
    if v < low - _TOLERANCE or v > high + _TOLERANCE:
        raise ValueError(f"{car}: action field '{name}'={v:.6g} is outside [{low:.6g}, {high:.6g}]")
    return min(high, max(low, v))


def parse_action(car: str, raw: Any, *, mode: str, max_yaw_rate: float) -> DrivingAction:
    """Turn what a caller passed for one car into a DrivingAction, or raise ValueError naming car and field.

    Accepted forms: a DrivingAction or a mapping {"throttle", "brake", "steering"} (either mode: the world always
    drives continuously); discrete mode — 2 integers [acceleration 0..2, steering 0..2]; continuous mode — 3 numbers
    [throttle, brake, steering]. Bounds: throttle [−1, 1], brake [0, 1], |steering| ≤ max_yaw_rate rad/s; a value
    beyond a bound is refused, except float round-off (1e-6), which is clamped.
    """
    if isinstance(raw, DrivingAction):
        values: Any = (raw.throttle, raw.brake, raw.steering)
    elif isinstance(raw, Mapping):
        if set(raw) != {"throttle", "brake", "steering"}:
            raise ValueError(f"{car}: action mapping needs exactly the keys 'throttle', 'brake' and 'steering', "
                             f"got {sorted(raw)}")
        values = (raw["throttle"], raw["brake"], raw["steering"])
    else:
        arr = np.asarray(raw)
        if arr.dtype.kind not in "iuf" or arr.dtype.kind == "b":
            raise ValueError(f"{car}: action must be numeric, got dtype {arr.dtype}")
        if mode == "discrete":
            if arr.shape != (2,):
                raise ValueError(f"{car}: discrete action must have shape (2,) [acceleration, steering], got shape "
                                 f"{arr.shape}")
            return discrete_action(_index(car, "acceleration", arr[0].item(), ACCELERATION_CHOICES),
                                   _index(car, "steering", arr[1].item(), STEERING_CHOICES), max_yaw_rate)
        if arr.shape != (3,):
            raise ValueError(f"{car}: continuous action must have shape (3,) [throttle, brake, steering], got shape "
                             f"{arr.shape}")
        values = tuple(v.item() for v in arr)
    return DrivingAction(_bounded(car, "throttle", values[0], -1.0, 1.0), _bounded(car, "brake", values[1], 0.0, 1.0),
                         _bounded(car, "steering", values[2], -max_yaw_rate, max_yaw_rate))


def next_speed(speed: float, action: DrivingAction, car_type: CarType, config: CarConfig, seconds: float) -> float:
    """Signed speed along the heading after one period of ``action``, from ``speed`` (the vehicle model's core).

    Traction first (forward gas only when not rolling backward, reverse only when not rolling forward: changing
    direction needs a stop, as in the original), then braking and rolling resistance toward zero, never past it.
    """
    u = speed
    stop = config.stop_speed
    if action.throttle > 0 and u > -stop:
        u = max(u, 0.0) + action.throttle * car_type.power * seconds
    elif action.throttle < 0 and u < stop:
        u = min(u, 0.0) + action.throttle * config.reverse_fraction * car_type.power * seconds
    slowing = (action.brake * config.brake_factor * car_type.power + config.rolling_per_kg * car_type.mass) * seconds
    return math.copysign(max(0.0, abs(u) - slowing), u) if u else 0.0


def yaw_rate_for(steering: float, speed: float, config: CarConfig) -> float:
    """Commanded yaw rate within the steering limit and the turning-radius limit |ω| ≤ |u| / R_min."""
    limit = min(config.max_yaw_rate, abs(speed) / config.min_turn_radius)
    return min(limit, max(-limit, steering))


# -- the car ---------------------------------------------------------------------------------------------------------
class Car:
    """One car: a dynamic box driven by ``Drive``, its destination and its rule state."""

    def __init__(self, index: int, team: int, car_type: CarType, config: CarConfig) -> None:
        self.index = index
        self.team = team
        self.type = car_type
        self.config = config
        size = (2 * car_type.half_length, 2 * car_type.half_width)
        self.body = pymunk.Body(car_type.mass, pymunk.moment_for_box(car_type.mass, size))
        self.shape = pymunk.Poly.create_box(self.body, size)
        self.shape.elasticity = config.elasticity
        self.shape.friction = config.friction
        self.shape.collision_type = CollisionType.CAR
        self.shape.filter = pymunk.ShapeFilter(categories=Category.CAR,
                                               mask=Category.CAR | Category.PEDESTRIAN | Category.STATIC)
        self.drive: Drive | None = None
        self.goal = 0                      # destination index (DrivingMap.destinations)
        self.goal_xy = (0.0, 0.0)
        self.start_end = 0                 # the road end it entered from
        self.finished = False
        self.crashed = False
        self.at_goal = False
        self.last_goal_distance = 0.0
        self.last_xy = (0.0, 0.0)
        self.in_opposing_lane = False
        self.in_space = False
        self._standing = False             # the drive's command is zero velocity and yaw rate

    def add_to(self, space: pymunk.Space) -> None:
        space.add(self.body, self.shape)
        c = self.config
        self.drive = Drive.attach(space, self.body, c.drive_accel * self.body.mass,
                                  c.drive_yaw_accel * self.body.moment)
        self.in_space = True

    def place(self, x: float, y: float, yaw: float, speed: float = 0.0) -> None:
        """Teleport between ticks, moving at ``speed`` along ``yaw``."""
        assert self.drive is not None
        self.drive.place(x, y, yaw)
        self._standing = not speed
        if speed:
            self.body.velocity = (speed * math.cos(yaw), speed * math.sin(yaw))
            self.drive.command(*self.body.velocity, 0.0)
        self.last_xy = (x, y)

    # -- state -----------------------------------------------------------------------------------------------
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
    def speed(self) -> float:
        """Signed speed along the heading, m/s."""
        v, a = self.body.velocity, self.body.angle
        return v.x * math.cos(a) + v.y * math.sin(a)

    @property
    def abs_velocity(self) -> float:
        return self.body.velocity.length

    # -- one period --------------------------------------------------------------------------------------------
    def apply(self, action: DrivingAction, seconds: float) -> None:
        """Set this period's command from the action (finished cars ignore it)."""
        if self.finished:
            return
        assert self.drive is not None
        body = self.body
        v, angle = body.velocity, body.angle
        speed = v.x * math.cos(angle) + v.y * math.sin(angle)
        u = next_speed(speed, action, self.type, self.config, seconds)
        omega = yaw_rate_for(action.steering, u, self.config)
        if u == 0.0 and omega == 0.0 and self._standing:
            return                                  # still standing: the command is already zero
        heading = angle + 0.5 * omega * seconds
        self.drive.command(u * math.cos(heading), u * math.sin(heading), omega)
        self._standing = u == 0.0 and omega == 0.0

    def finish(self, crashed: bool, at_goal: bool = False) -> None:
        """Out of the game: brake to a stop with the original's high friction and ignore further actions."""
        self.finished = True
        self.crashed = crashed
        self.at_goal = at_goal
        assert self.drive is not None
        c = self.config
        self.drive.pivot.max_force = c.finished_per_kg * self.body.mass * self.body.mass
        self.drive.gear.max_force = c.finished_spin * self.body.moment
        self.drive.command(0.0, 0.0, 0.0)

    def leave(self, space: pymunk.Space) -> None:
        """Drive off the map (destination reached): out of the physics world, at rest where it left."""
        assert self.drive is not None
        self.body.velocity = (0.0, 0.0)
        self.body.angular_velocity = 0.0
        space.remove(self.body, self.shape, self.drive.control, self.drive.pivot, self.drive.gear)
        self.in_space = False


__all__ = ["CollisionType", "Category", "CarType", "car_types", "DrivingAction", "BRAKE", "discrete_action",
           "parse_action", "next_speed", "yaw_rate_for", "Car", "ACCELERATION_CHOICES", "STEERING_CHOICES"]
