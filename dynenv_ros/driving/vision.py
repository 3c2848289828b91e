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


def driving_state(world: DrivingWorld) -> DrivingState:
    """The world now, as perception's arrays (cars that left the world are marked absent)."""
    values = []
    for car in world.cars:
        body = car.body
        (x, y), (vx, vy), angle = body.position, body.velocity, body.angle
        values += (x, y, angle, vx * math.cos(angle) + vy * math.sin(angle), body.angular_velocity, car.in_space,
                   car.crashed, car.finished, car.goal_xy[0], car.goal_xy[1])
    table = np.array(values, float).reshape(-1, 10)
    peds = world.pedestrians
    xy = np.array([tuple(b.position) for b in peds.bodies], float).reshape(-1, 2)
    return DrivingState(x=table[:, 0], y=table[:, 1], yaw=np.remainder(table[:, 2] + math.pi, 2 * math.pi) - math.pi,
                        speed=table[:, 3], yaw_rate=table[:, 4], present=table[:, 5] > 0, crashed=table[:, 6] > 0,
                        finished=table[:, 7] > 0, goal_x=table[:, 8], goal_y=table[:, 9], pedestrian_x=xy[:, 0],
                        pedestrian_y=xy[:, 1], pedestrian_alive=peds.alive.copy())


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

    def perceive(self) -> DrivingPerception:
        """Every car's reports of the world as it is now (view v = car v; object ids = the snapshot's ids)."""
        return self.perceiver.perceive(driving_state(self.world), self.rng)


__all__ = ["DrivingVision", "driving_scene", "driving_state", "map_lanes", "map_buildings"]
