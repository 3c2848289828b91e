"""The driving world seen through each car's sensors: turns a ``DrivingWorld``'s state into the perception inputs and
returns, per car, its detection rows (docs/perception.md, "Driving").

    vision = DrivingVision(world, load_driving_preset("realistic"))
    world.step(actions)
    perception = vision.perceive()          # after every step: one frame per 100 ms period
    rows = perception.of_view(car)          # DETECTION_DTYPE rows in the car's frame, SELF row first

Call ``reset()`` after ``world.reset()`` (new cars, pedestrians, obstacles). Random draws come from one
``numpy.random.Generator``: the one passed as ``rng``, else the world's own (``world.rng``, re-seeded by
``world.reset(seed=…)``), never numpy's global state.
"""
from __future__ import annotations

import math

import numpy as np
import pymunk
import pymunk.batch

from dynenv_ros.driving.roads import DrivingMap
from dynenv_ros.driving.world import DrivingWorld
from dynenv_ros.perception.driving_model import (LANE_CENTRE, ROAD_EDGE, DrivingPerceiver, DrivingPerception,
                                                 DrivingScene, DrivingState)
from dynenv_ros.perception.driving_params import DrivingPerceptionParams, load_driving_preset


def map_lanes(dmap: DrivingMap) -> tuple[np.ndarray, np.ndarray]:
    """(L, 4) segments and (L,) kinds: every lane centre in its direction of travel, then each road's two edges."""
    rows = [[c.x1, c.y1, c.x2, c.y2] for c in dmap.lane_centres]
    kinds = [LANE_CENTRE] * len(rows)
    for line in dmap.lane_lines:
        if int(line.kind) == 1:                                   # LineKind.EDGE
            rows.append([line.x1, line.y1, line.x2, line.y2])
            kinds.append(ROAD_EDGE)
    return np.asarray(rows, float), np.asarray(kinds, int)


def map_buildings(dmap: DrivingMap) -> np.ndarray:
    """(B, 5) centre x, y, half sizes, yaw (the map's buildings are axis-aligned: yaw 0)."""
    return np.asarray([[b.x, b.y, b.half_x, b.half_y, 0.0] for b in dmap.buildings], float).reshape(-1, 5)


def driving_scene(world: DrivingWorld) -> DrivingScene:
    lanes, kinds = map_lanes(world.map)
    cfg = world.config
    return DrivingScene(
        car_half_length=np.array([car.type.half_length for car in world.cars], float),
        car_half_width=np.array([car.type.half_width for car in world.cars], float),
        car_team=np.array([car.team for car in world.cars], np.int8),
        n_pedestrians=len(world.pedestrians), pedestrian_radius=cfg.pedestrians.radius,
        obstacle_xy=np.asarray(world.obstacles_xy, float).reshape(-1, 2), obstacle_half=cfg.obstacles.size / 2,
        buildings=map_buildings(world.map), lanes=lanes, lane_kind=kinds, lane_width=cfg.map.lane_width)


_BODY_FIELDS = (pymunk.batch.BodyFields.BODY_ID | pymunk.batch.BodyFields.POSITION | pymunk.batch.BodyFields.ANGLE
                | pymunk.batch.BodyFields.VELOCITY | pymunk.batch.BodyFields.ANGULAR_VELOCITY)


class BodyTable:
    """The pose and velocity of every car and pedestrian of one world, read from pymunk in one batch call.

    Why: reading them body by body through pymunk's Python properties cost ≈ 28 µs per frame for 2 cars and 19
    pedestrians, ≈ 7 % of a driving env step; ``pymunk.batch`` copies the whole space's bodies in ≈ 3 µs. Bodies
    out of the space (a car that left at its destination, a pedestrian that was hit) are read one by one, as before.
    Rows: cars first, then pedestrians; columns x, y, angle, vx, vy, angular velocity (map frame).
    """

    def __init__(self, world: DrivingWorld) -> None:
        self.bodies = [car.body for car in world.cars] + list(world.pedestrians.bodies)
        ids = np.array([body.id for body in self.bodies], np.int64)
        self._order = np.argsort(ids)
        self._sorted_ids = ids[self._order]
        self._buffer = pymunk.batch.Buffer()
        self._ids: np.ndarray | None = None          # the batch's body ids at the last read, and their rows
        self._mine = self._rows = self._absent = np.zeros(0, np.intp)

    def read(self, space: pymunk.Space) -> np.ndarray:
        """A new (bodies, 6) table of the bodies now (a new array each call: states made from it stay as they were)."""
        self._buffer.clear()
        pymunk.batch.get_space_bodies(space, _BODY_FIELDS, self._buffer)
        ids = np.frombuffer(self._buffer.int_buf(), np.int64)
        if self._ids is None or not np.array_equal(ids, self._ids):   # bodies left or joined: map the rows anew
            self._ids = ids.copy()
            at = np.minimum(np.searchsorted(self._sorted_ids, ids), len(self._sorted_ids) - 1)
            self._mine = (self._sorted_ids[at] == ids).nonzero()[0]  # the space's other bodies (a car's controls)
            self._rows = self._order[at[self._mine]]
            self._absent = np.setdiff1d(np.arange(len(self.bodies)), self._rows)
        values = np.frombuffer(self._buffer.float_buf(), np.float64).reshape(-1, 6)
        table = np.empty((len(self.bodies), 6))
        table[self._rows] = values[self._mine]
        for i in self._absent:
            body = self.bodies[i]
            (x, y), (vx, vy) = body.position, body.velocity
            table[i] = (x, y, body.angle, vx, vy, body.angular_velocity)
        return table


def driving_state(world: DrivingWorld, bodies: BodyTable | None = None) -> DrivingState:
    """The world now, as perception's arrays (cars that left the world are marked absent). ``bodies``: a
    ``BodyTable`` of this world to read it with (made here when not given)."""
    table = (bodies or BodyTable(world)).read(world.physics.space)
    n = len(world.cars)
    cars = np.array([(car.in_space, car.crashed, car.finished, car.goal_xy[0], car.goal_xy[1]) for car in world.cars],
                    float).reshape(-1, 5)
    angle = table[:n, 2]
    return DrivingState(x=table[:n, 0], y=table[:n, 1], yaw=np.remainder(angle + math.pi, 2 * math.pi) - math.pi,
                        speed=table[:n, 3] * np.cos(angle) + table[:n, 4] * np.sin(angle), yaw_rate=table[:n, 5],
                        present=cars[:, 0] > 0, crashed=cars[:, 1] > 0, finished=cars[:, 2] > 0, goal_x=cars[:, 3],
                        goal_y=cars[:, 4], pedestrian_x=table[n:, 0], pedestrian_y=table[n:, 1],
                        pedestrian_alive=world.pedestrians.alive.copy())


class DrivingVision:
    """One perceiver per episode over one world; ``perceive()`` once per period, after ``world.step``."""

    def __init__(self, world: DrivingWorld, params: DrivingPerceptionParams | str = "realistic",
                 rng: np.random.Generator | None = None) -> None:
        self.world = world
        self.params = load_driving_preset(params) if isinstance(params, str) else params
        self._rng = rng
        self.reset()

    @property
    def rng(self) -> np.random.Generator:
        return self._rng if self._rng is not None else self.world.rng

    def reset(self, rng: np.random.Generator | None = None) -> None:
        """After ``world.reset``; a new ``rng`` replaces the one given at construction."""
        if rng is not None:
            self._rng = rng
        self.scene = driving_scene(self.world)
        self.perceiver = DrivingPerceiver(self.scene, self.params)
        self.bodies = BodyTable(self.world)

    def perceive(self) -> DrivingPerception:
        """Every car's reports of the world as it is now (view v = car v; object ids = the snapshot's ids)."""
        return self.perceiver.perceive(driving_state(self.world, self.bodies), self.rng)


__all__ = ["BodyTable", "DrivingVision", "driving_scene", "driving_state", "map_lanes", "map_buildings"]
