"""Pedestrians: walk along their walkway, now and then cross their road (docs/original.md §3 numbers, × 0.1 m/px).

Each pedestrian keeps to one walkway stretch (``DrivingMap.walkway_segments``: between a map edge and the other
road) and only steps onto the carriageway to cross to the opposite stretch. A movement is a constant velocity
held by a kinematic body, so between changes pymunk moves it and Python does nothing: the world calls
``update(tick)`` once per period, which returns at once unless some pedestrian's movement is due to change
(its time is up, it reached the end of its stretch, or it finished crossing).

Movements, as the original: base speed randint(3, 6) px/s (0.3–0.6 m/s); each movement lasts randint(5000, 30000)
ms; with probability 5 % it is a crossing at base · randint(1, 2) straight across the road, otherwise a walk at
base · randint(−2, 2) along the walkway (0: standing). A crossing lasts until the far walkway (a pedestrian never
stops on the road); at the end of its stretch (the map edge or the other road) a pedestrian turns back.

Bodies are kinematic sensors: a car's contact is reported to the world (which decides whether the pedestrian is
hit) but neither pushes the other. Pedestrian–pedestrian and pedestrian–obstacle contacts do not exist (filters).
"""
from __future__ import annotations

import math

import numpy as np
import pymunk

from dynenv_ros.driving.cars import Category, CollisionType
from dynenv_ros.driving.config import PedestrianConfig
from dynenv_ros.driving.roads import DrivingMap

WALK, CROSS = 0, 1
_NEVER = np.iinfo(np.int64).max


class Pedestrians:
    """All pedestrians of one world; index i is pedestrian i (its snapshot id is the world's ``first_id + i``)."""

    def __init__(self, rng: np.random.Generator, config: PedestrianConfig, dmap: DrivingMap, tick_seconds: float,
                 count: int) -> None:
        self.rng = rng
        self.config = config
        self.map = dmap
        self.tick_seconds = tick_seconds
        segments = dmap.walkway_segments
        lane = dmap.config.lane_width
        weights = np.array([s.length for s in segments])
        self.segment = rng.choice(len(segments), size=count, p=weights / weights.sum()).astype(np.int64)
        self.base = rng.integers(config.base_speed_min, config.base_speed_max + 1, size=count) * config.speed_unit
        self.mode = np.full(count, WALK, dtype=np.int64)
        self.due = np.zeros(count, dtype=np.int64)
        self.alive = np.ones(count, dtype=bool)
        self.death_xy = np.zeros((count, 2))
        self.bodies: list[pymunk.Body] = []
        self.shapes: list[pymunk.Circle] = []
        for i in range(count):
            seg = segments[self.segment[i]]
            road = dmap.roads[seg.road]
            r = config.radius
            s = rng.uniform(seg.s_min + r, seg.s_max - r)
            d = seg.side * (seg.inner + rng.uniform(config.lateral_min, config.lateral_max) * lane)
            body = pymunk.Body(body_type=pymunk.Body.KINEMATIC)
            body.position = road.to_map(s, d)
            shape = pymunk.Circle(body, r)
            shape.sensor = True
            shape.collision_type = CollisionType.PEDESTRIAN
            shape.filter = pymunk.ShapeFilter(categories=Category.PEDESTRIAN, mask=Category.CAR)
            self.bodies.append(body)
            self.shapes.append(shape)
        self._index_of_shape = {shape: i for i, shape in enumerate(self.shapes)}
        self.next_due = 0                     # every pedestrian picks its first movement at the first update

    def __len__(self) -> int:
        return len(self.bodies)

    def add_to(self, space: pymunk.Space) -> None:
        for body, shape in zip(self.bodies, self.shapes):
            space.add(body, shape)

    def index_of(self, shape: pymunk.Shape) -> int | None:
        return self._index_of_shape.get(shape)

    # -- movements ----------------------------------------------------------------------------------------------
    def update(self, tick: int) -> None:
        """Start new movements for the pedestrians whose movement is due (cheap when none is)."""
        if tick < self.next_due:
            return
        for i in np.flatnonzero(self.due <= tick):
            self._new_movement(int(i), tick)
        self.next_due = int(self.due.min()) if len(self.due) else _NEVER

    def _new_movement(self, i: int, tick: int) -> None:
        c = self.config
        rng = self.rng
        segments = self.map.walkway_segments
        seg = segments[self.segment[i]]
        road = self.map.roads[seg.road]
        body = self.bodies[i]
        s, d = road.to_road(*body.position)
        if self.mode[i] == CROSS:               # arrived on the far walkway
            self.segment[i] = self._opposite(int(self.segment[i]))
            seg = segments[self.segment[i]]
        r = c.radius
        ux, uy = road.direction
        if rng.random() < c.cross_probability:
            speed = self.base[i] * int(rng.integers(c.cross_multiplier_min, c.cross_multiplier_max + 1))
            across = -math.copysign(1.0, d)      # toward the other side; normal to the left is (−uy, ux)
            body.velocity = (-uy * across * speed, ux * across * speed)
            self.mode[i] = CROSS
            seconds = 2.0 * abs(d) / speed       # mirror image of its lateral offset on the far walkway
        else:
            multiplier = int(rng.integers(-c.walk_multiplier_max, c.walk_multiplier_max + 1))
            speed = self.base[i] * multiplier
            # At (or past) an end of its stretch a pedestrian walks back inside.
            if (s >= seg.s_max - r and speed > 0) or (s <= seg.s_min + r and speed < 0):
                speed = -speed
            body.velocity = (ux * speed, uy * speed)
            self.mode[i] = WALK
            seconds = int(rng.integers(c.movement_ms_min, c.movement_ms_max + 1)) / 1000.0
            if speed > 0:
                seconds = min(seconds, max(0.0, (seg.s_max - r - s) / speed))
            elif speed < 0:
                seconds = min(seconds, max(0.0, (s - seg.s_min - r) / -speed))
        self.due[i] = tick + max(1, math.ceil(seconds / self.tick_seconds - 1e-9))

    def _opposite(self, index: int) -> int:
        seg = self.map.walkway_segments[index]
        for j, other in enumerate(self.map.walkway_segments):
            if other.road == seg.road and other.side == -seg.side and other.s_min == seg.s_min:
                return j
        raise RuntimeError(f"walkway segment {index} has no opposite")   # pragma: no cover (map geometry)

    def kill(self, i: int, space: pymunk.Space) -> None:
        """Hit by a car: out of the physics world, still listed (status CRASHED) where it fell."""
        if not self.alive[i]:
            return
        self.alive[i] = False
        self.death_xy[i] = tuple(self.bodies[i].position)
        self.due[i] = _NEVER
        self.bodies[i].velocity = (0.0, 0.0)
        space.remove(self.bodies[i], self.shapes[i])
        self.next_due = int(self.due.min())

    # -- test and demo helpers ------------------------------------------------------------------------------------
    def place(self, i: int, x: float, y: float, vx: float = 0.0, vy: float = 0.0, hold_seconds: float = 1e6,
              tick: int = 0) -> None:
        """Put a pedestrian somewhere with a fixed velocity for ``hold_seconds`` (tests, demos)."""
        body = self.bodies[i]
        body.position = (x, y)
        body.velocity = (vx, vy)
        self.mode[i] = WALK
        self.due[i] = tick + max(1, math.ceil(hold_seconds / self.tick_seconds))
        self.next_due = int(self.due.min())
        if body.space is not None:
            body.space.reindex_shapes_for_body(body)


__all__ = ["Pedestrians", "WALK", "CROSS"]
