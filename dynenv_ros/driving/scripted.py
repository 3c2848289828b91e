"""A scripted driver: keeps its right lane along a route to its destination, turns at the crossing, yields.

It reads only ground truth (a ``WorldSnapshot``, or a ``DrivingWorld`` whose snapshot it takes) and the map of the
config, so the same code can drive a car from the ROS WorldState topic. Stateless: each decision is a function of
the snapshot.

Route: the centre of the car's current lane up to the crossing, a circular arc (radius 6 m turning left, 5 m
turning right: both keep the car's centre on the road at the corners, docs/driving.md) into the lane next to the
centre line of the destination's road, then that lane past the road end. Steering: pure pursuit on the route.
Speed: cruise speed on straights, the arc's speed (the steering limit times the radius) on arcs, braking early
enough for both (planned at 3 m/s², well below the cars' real braking). Yielding: the car stops short of any
pedestrian (predicted ahead at constant velocity), obstacle or car in its route's corridor; at the crossing it
waits outside while a car whose route through the crossing conflicts with its own is inside, or is nearer to it
(first come, first served; see ``ScriptedDriver``).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from dynenv_ros.core.object_classes import ObjectClass, ObjectStatus
from dynenv_ros.driving.cars import ACCELERATION_CHOICES, DrivingAction
from dynenv_ros.driving.config import DrivingConfig
from dynenv_ros.driving.roads import DrivingMap
from dynenv_ros.sim.ground_truth import BodyState, WorldSnapshot

_DONE = ObjectStatus.FINISHED
_GAS, _BRAKE = ACCELERATION_CHOICES - 1, 1


@dataclass(frozen=True)
class Route:
    """Points every ``spacing`` metres from the car's position along its lane(s); ``turning`` marks arc points."""
    points: np.ndarray          # (K, 2)
    arc: np.ndarray             # (K,) distance along the route from its first point
    turning: np.ndarray         # (K,) bool
    radius: float               # of the turn, 0 for a straight route

    def heading_at(self, i: int) -> float:
        j = min(i + 1, len(self.points) - 1)
        i = j - 1 if j > 0 else 0
        d = self.points[j] - self.points[i]
        return math.atan2(d[1], d[0])


def find_car(snapshot: WorldSnapshot, car_id: int) -> BodyState:
    for o in snapshot.objects:
        if o.class_id == ObjectClass.CAR and o.id == car_id:
            return o
    raise KeyError(f"no car with id {car_id} in the snapshot")


def current_road(dmap: DrivingMap, x: float, y: float, yaw: float) -> tuple[int, int] | None:
    """(road, direction sign) of the road the car drives along: the best-aligned road whose width it is on."""
    best, best_align = None, -1.0
    margin = dmap.config.off_road_margin
    for r, road in enumerate(dmap.roads):
        s, d = road.to_road(x, y)
        if abs(d) >= road.half_width + margin:
            continue
        align = math.cos(road.heading - yaw)
        if abs(align) > best_align:
            best, best_align = (r, 1 if align >= 0 else -1), abs(align)
    return best


def _segment(a: np.ndarray, b: np.ndarray, spacing: float) -> np.ndarray:
    n = max(1, math.ceil(float(np.hypot(*(b - a))) / spacing))
    t = np.linspace(0.0, 1.0, n + 1)[:, None]
    return a + t * (b - a)


def plan_route(dmap: DrivingMap, x: float, y: float, yaw: float, goal: int, *, radius_left: float = 6.0,
               radius_right: float = 5.0, spacing: float = 0.5, beyond: float = 8.0) -> Route | None:
    """The route from a car's pose to road end ``goal``, or None when the car cannot get there by driving ahead
    (off every road, its destination behind it)."""
    here = current_road(dmap, x, y, yaw)
    if here is None:
        return None
    r, sign = here
    road = dmap.roads[r]
    s, d = road.to_road(x, y)
    k = int(np.argmin([abs(d - road.lane_offset(sign, j)) for j in range(road.lanes)]))
    d_lane = road.lane_offset(sign, k)
    goal_road, goal_end = dmap.road_of_end(goal)
    e1 = np.array(road.direction) * sign
    start = np.array(road.to_map(s, d_lane))
    if goal_road == r:
        if goal_end != sign:
            return None
        end_s = road.length + beyond if sign > 0 else -beyond
        points = _segment(start, np.array(road.to_map(end_s, d_lane)), spacing)
        return _route(points, np.zeros(len(points), dtype=bool), 0.0)
    other = dmap.roads[goal_road]
    sign_g = goal_end
    d_g = other.lane_offset(sign_g, 0)
    e2 = np.array(other.direction) * sign_g
    # Corner: where the two lane centres cross.
    a0 = np.array(road.to_map(0.0, d_lane))
    b0 = np.array(other.to_map(0.0, d_g))
    u, v = np.array(road.direction), np.array(other.direction)
    t = np.linalg.solve(np.column_stack([u, -v]), b0 - a0)[0]
    corner = a0 + t * u
    if float(np.dot(start - corner, e1)) > other.half_width:
        return None                                   # already past the crossing
    left = e1[0] * e2[1] - e1[1] * e2[0] > 0
    radius = radius_left if left else radius_right
    t1, t2 = corner - e1 * radius, corner + e2 * radius
    normal = np.array([-e1[1], e1[0]]) * (1.0 if left else -1.0)
    centre = t1 + normal * radius
    a_start = math.atan2(*(t1 - centre)[::-1])
    sweep = math.pi / 2 * (1.0 if left else -1.0)
    n_arc = max(2, math.ceil(abs(sweep) * radius / spacing))
    angles = a_start + np.linspace(0.0, sweep, n_arc + 1)
    arc = centre + radius * np.column_stack([np.cos(angles), np.sin(angles)])
    end_s = other.length + beyond if sign_g > 0 else -beyond
    tail = _segment(t2, np.array(other.to_map(end_s, d_g)), spacing)[1:]
    if float(np.dot(start - t1, e1)) < 0:
        head = _segment(start, t1, spacing)[:-1]
        turning = np.concatenate([np.zeros(len(head), bool), np.ones(len(arc), bool), np.zeros(len(tail), bool)])
        points = np.concatenate([head, arc, tail])
    else:   # on the arc already: start from its point nearest to the car
        nearest = int(np.argmin(np.hypot(arc[:, 0] - x, arc[:, 1] - y)))
        arc = arc[nearest:]
        turning = np.concatenate([np.ones(len(arc), bool), np.zeros(len(tail), bool)])
        points = np.concatenate([arc, tail])
    return _route(points, turning, radius)


def _route(points: np.ndarray, turning: np.ndarray, radius: float) -> Route:
    steps = np.hypot(*np.diff(points, axis=0).T) if len(points) > 1 else np.zeros(0)
    return Route(points, np.concatenate([[0.0], np.cumsum(steps)]), turning, radius)


@dataclass(frozen=True)
class _Plan:
    """One car's route and how it meets the crossing box."""
    car: BodyState
    route: Route | None
    near: int = 0                       # route index nearest to the car
    inside: bool = False                # the car is in the crossing box
    entry: float = math.inf             # route distance to the box (0 inside, inf when the route avoids it)
    box_points: np.ndarray | None = None


class ScriptedDriver:
    """Drives every car of a snapshot; ``act`` gives one car's action in the world's action format.

    The crossing is a shared box (both carriageways' overlap plus ``box_margin``): a car enters it only when no
    car whose route through it comes within ``conflict_distance`` of its own is inside, nor such a car nearer to
    the box (within ``priority_distance``; equal distances: the lower id) is about to enter. First come, first
    served: a car queued behind another is farther from the box than the one it follows, so waiting never goes
    round in a circle, and cars in the box never block each other.
    """

    def __init__(self, config: DrivingConfig | None = None, cruise_speed: float = 10.0,
                 planning_deceleration: float = 3.0, radius_left: float = 6.0, radius_right: float = 5.0,
                 stop_gap: float = 2.0, lateral_margin: float = 0.6, pedestrian_horizon: float = 4.0,
                 box_margin: float = 1.0, conflict_distance: float = 2.5, priority_distance: float = 30.0) -> None:
        self.config = config or DrivingConfig()
        self.map = DrivingMap(self.config.map)
        self.cruise_speed = cruise_speed
        self.deceleration = planning_deceleration
        self.radius_left, self.radius_right = radius_left, radius_right
        self.stop_gap = stop_gap
        self.lateral_margin = lateral_margin
        self.pedestrian_horizon = pedestrian_horizon
        self.conflict_distance = conflict_distance
        self.priority_distance = priority_distance
        self.max_yaw_rate = self.config.cars.max_yaw_rate
        vertical, horizontal = self.map.roads
        cx, cy = self.map.crossing
        self.box = (cx - vertical.half_width - box_margin, cy - horizontal.half_width - box_margin,
                    cx + vertical.half_width + box_margin, cy + horizontal.half_width + box_margin)

    # -- public -------------------------------------------------------------------------------------------------
    def actions(self, source: Any) -> list[Any]:
        """Every car's action from one snapshot (or a world), in car order."""
        snapshot = self._snapshot(source)
        plans = self._plans(snapshot)
        return [self._format(self._decide(snapshot, plans[i], plans)) for i in sorted(plans)]

    def act(self, source: Any, car_id: int) -> Any:
        return self._format(self.decide(source, car_id))

    def decide(self, source: Any, car_id: int) -> DrivingAction:
        """The continuous command behind ``act``."""
        snapshot = self._snapshot(source)
        plans = self._plans(snapshot)
        if car_id not in plans:
            raise KeyError(f"no car with id {car_id} in the snapshot")
        return self._decide(snapshot, plans[car_id], plans)

    def route(self, car: BodyState) -> Route | None:
        if car.status & _DONE or not math.isfinite(car.goal_x):
            return None
        goal = self.map.nearest_end(car.goal_x, car.goal_y)
        return plan_route(self.map, car.x, car.y, car.yaw, goal, radius_left=self.radius_left,
                          radius_right=self.radius_right)

    # -- planning ------------------------------------------------------------------------------------------------
    @staticmethod
    def _snapshot(source: Any) -> WorldSnapshot:
        return source if isinstance(source, WorldSnapshot) else source.snapshot()

    def _in_box(self, points: np.ndarray) -> np.ndarray:
        x0, y0, x1, y1 = self.box
        return (points[:, 0] > x0) & (points[:, 0] < x1) & (points[:, 1] > y0) & (points[:, 1] < y1)

    def _plans(self, snapshot: WorldSnapshot) -> dict[int, _Plan]:
        plans = {}
        for car in snapshot.of_class(ObjectClass.CAR):
            route = self.route(car)
            if route is None or len(route.points) < 2:
                plans[car.id] = _Plan(car, None)
                continue
            pts = route.points
            near = int(np.argmin(np.hypot(pts[:80, 0] - car.x, pts[:80, 1] - car.y)))
            in_box = self._in_box(pts)
            inside = bool(self._in_box(np.array([[car.x, car.y]]))[0])
            ahead = np.flatnonzero(in_box[near:])
            entry = 0.0 if inside else float(route.arc[near + ahead[0]] - route.arc[near]) if len(ahead) else math.inf
            plans[car.id] = _Plan(car, route, near, inside, entry, pts[near:][in_box[near:]] if len(ahead) else None)
        return plans

    # -- decision ----------------------------------------------------------------------------------------------
    def _format(self, action: DrivingAction) -> np.ndarray:
        if self.config.action_mode == "continuous":
            return np.array([action.throttle, action.brake, action.steering])
        accel = _GAS if action.throttle > 0 else _BRAKE
        w = self.max_yaw_rate
        steer = 2 if action.steering > 0.5 * w else 0 if action.steering < -0.5 * w else 1
        return np.array([accel, steer], dtype=np.int64)

    def _decide(self, snapshot: WorldSnapshot, plan: _Plan, plans: dict[int, _Plan]) -> DrivingAction:
        car, route = plan.car, plan.route
        if route is None:
            return DrivingAction(brake=1.0)
        c, s = math.cos(car.yaw), math.sin(car.yaw)
        speed = car.vx * c + car.vy * s
        pts, near = route.points, plan.near
        here = route.arc[near]
        # Speed: cruise, slow for the arc ahead, and for a large heading error (finishing a turn).
        turn_speed = 0.9 * self.max_yaw_rate * (route.radius or self.radius_right)
        limits = np.where(route.turning, turn_speed, self.cruise_speed)
        reach = np.sqrt(limits[near:] ** 2 + 2 * self.deceleration * np.maximum(route.arc[near:] - here, 0.0))
        target = float(min(self.cruise_speed, reach.min()))
        lookahead = min(8.0, max(2.0, 1.5 + 0.5 * abs(speed)))
        j = min(int(np.searchsorted(route.arc, here + lookahead)), len(pts) - 1)
        if abs(math.remainder(route.heading_at(j) - car.yaw, math.tau)) > 0.25:
            target = min(target, turn_speed)
        gaps = [self._free_distance(snapshot, car, route, near), self._box_wait(plan, plans)]
        gaps = [g for g in gaps if g is not None]
        if gaps:
            target = min(target, math.sqrt(2 * self.deceleration * max(0.0, min(gaps) - self.stop_gap)))
        # Pure pursuit toward the look-ahead point.
        dx, dy = pts[j, 0] - car.x, pts[j, 1] - car.y
        fx, fy = c * dx + s * dy, -s * dx + c * dy
        curvature = 2.0 * fy / max(fx * fx + fy * fy, 1e-6)
        steering = max(-self.max_yaw_rate, min(self.max_yaw_rate, curvature * max(abs(speed), 0.5)))
        if target < 0.05:
            return DrivingAction(brake=1.0, steering=steering)
        if speed < target:
            return DrivingAction(throttle=min(1.0, 0.3 + (target - speed)), steering=steering)
        return DrivingAction(brake=min(1.0, 0.5 * (speed - target)), steering=steering)

    def _box_wait(self, plan: _Plan, plans: dict[int, _Plan]) -> float | None:
        """Distance from the car's front to the crossing box when it must wait outside it, else None."""
        if plan.inside or plan.box_points is None:
            return None
        if plan.entry > self.cruise_speed ** 2 / (2 * self.deceleration) + 2 * self.stop_gap + plan.car.size_x:
            return None
        for other in plans.values():
            if other.car.id == plan.car.id or other.box_points is None:
                continue
            first = (other.entry, other.car.id) < (plan.entry, plan.car.id)
            if not (other.inside or (first and other.entry < self.priority_distance)):
                continue
            a, b = plan.box_points, other.box_points
            gap = np.hypot(a[:, None, 0] - b[None, :, 0], a[:, None, 1] - b[None, :, 1]).min()
            if gap < self.conflict_distance:
                return plan.entry - plan.car.size_x / 2
        return None

    def _free_distance(self, snapshot: WorldSnapshot, car: BodyState, route: Route, near: int) -> float | None:
        """Distance along the route from the car's front to the nearest thing in its way, or None."""
        here = route.arc[near]
        reach = 2 * car.size_x + self.cruise_speed ** 2 / (2 * self.deceleration) + self.stop_gap
        window = (route.arc >= here) & (route.arc <= here + reach)
        pts, arcs = route.points[window], route.arc[window] - here
        if len(pts) < 2:
            return None
        half_width = car.size_y / 2
        best: float | None = None
        for other in snapshot.objects:
            if other.id == car.id:
                continue
            predicted = self._predict(other, car)
            if predicted is None:
                continue
            positions, lateral_extent, along_extent = predicted
            dist = np.hypot(positions[:, None, 0] - pts[None, :, 0], positions[:, None, 1] - pts[None, :, 1])
            nearest = dist.argmin(axis=1)
            inside = dist.min(axis=1) < half_width + lateral_extent + self.lateral_margin
            inside &= ~((nearest == 0) & (((positions - pts[0]) @ (pts[1] - pts[0])) < 0))   # not behind
            if not inside.any():
                continue
            along = arcs[nearest][inside].min() - car.size_x / 2 - along_extent
            best = along if best is None else min(best, along)
        return best

    def _predict(self, other: BodyState, car: BodyState) -> tuple[np.ndarray, float, float] | None:
        """Where another object may be over the next seconds (rows of x, y), and its half extents across and
        along this car's way. Cars: where they are (the crossing box settles who goes first)."""
        if other.class_id == ObjectClass.PEDESTRIAN:
            if other.status & ObjectStatus.CRASHED:
                return None
            times = np.linspace(0.0, self.pedestrian_horizon, 9)[:, None]
            r = other.size_x / 2
            return np.array([other.x, other.y]) + times * np.array([other.vx, other.vy]), r, r
        if other.class_id == ObjectClass.OBSTACLE:
            return np.array([[other.x, other.y]]), other.size_x / 2, other.size_x / 2
        if other.class_id != ObjectClass.CAR or other.status & ObjectStatus.AT_GOAL:
            return None
        rel = other.yaw - car.yaw
        hl, hw = other.size_x / 2, other.size_y / 2
        return (np.array([[other.x, other.y]]), abs(math.sin(rel)) * hl + abs(math.cos(rel)) * hw,
                abs(math.cos(rel)) * hl + abs(math.sin(rel)) * hw)


def drive(world: Any, driver: ScriptedDriver | None = None, periods: int | None = None) -> list:
    """Run a world with every car scripted until the episode ends (or ``periods``); return all events."""
    driver = driver or ScriptedDriver(world.config)
    events = []
    count = 0
    while not world.done and (periods is None or count < periods):
        events += world.step(driver.actions(world.snapshot())).events
        count += 1
    return events


__all__ = ["ScriptedDriver", "Route", "plan_route", "current_road", "find_car", "drive"]
