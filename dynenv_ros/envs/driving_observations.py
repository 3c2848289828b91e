"""What a driving agent observes each motion period: the observation seam of ``driving_v0`` and its ``full`` mode.

The env talks to its observations through one small interface (``DrivingObservationBuilder``): ``reset(world)``,
``on_frame(k)`` at every vision instant of a period (hooked into ``DrivingWorld.step``), ``initial()`` after a reset,
``build()`` after a period (one observation per car and the observation reward per car), ``infos(i)`` for extra
per-agent info, and ``space``. A mode is a factory in ``OBSERVATION_BUILDERS`` (or added with
``register_observation``), called as ``factory(config, perception=…, **options)``; the env never names a mode
itself, so a perception-based mode (``partial``, ``padded``) plugs in here without touching the env class.

``full`` (this module): the original's FULL observation (docs/original.md §4.6) as noise-free ground truth in the
**observer's frame** (REP 103: x forward along the car's heading, y to its left; metres, seconds, radians, m/s), one
flat float32 ``Box``. Sections, in this order (``FullLayout.split`` cuts a vector into them):

| section | rows × columns | columns |
|---|---|---|
| ``self`` | 1 × 15 | x, y, cos_yaw, sin_yaw (map-frame pose: the one absolute quantity), speed, lateral_speed (own velocity in its frame), yaw_rate, length, width, goal_x, goal_y (destination in its frame), finished, crashed, at_goal, time_remaining (s) |
| ``cars`` | (n_cars − 1) × 12 | present, x, y, cos_yaw, sin_yaw (heading relative to the observer), vx, vy (velocity in the observer's frame), length, width, finished, crashed, same_team (+1 / −1); one slot per other car in id order; absent (zeros) once it reached its destination and left the map |
| ``pedestrians`` | pedestrians.count_max × 5 | present, x, y, vx, vy; nearest first, zero-padded (a hit pedestrian has left the world) |
| ``obstacles`` | obstacles.count_max × 7 | present, x, y, cos_yaw, sin_yaw (the box's orientation relative to the observer), length, width; nearest first, zero-padded |
| ``lanes`` | lane lines × 5 | x1, y1, x2, y2, kind (1 road edge, −1 centre line, 0 between lanes of one direction), every painted line of the map (8 by default) in ``DrivingMap.lane_lines`` order |

``present`` is the row mask (1 a body, 0 padding). Values are clipped to the space's bounds. Full mode pays no
observation reward (as the original's driving scenario). ``DrivingGroundTruth.state`` is the env's ``state()``: the
same bodies in the map frame.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Callable, Mapping, Protocol

import numpy as np
from gymnasium import spaces

from dynenv_ros.core.object_classes import ObjectClass, ObjectStatus
from dynenv_ros.driving.config import DrivingConfig
from dynenv_ros.driving.roads import DrivingMap
from dynenv_ros.perception.params import resolve_setting
from dynenv_ros.sim.ground_truth import WorldSnapshot

SELF_COLUMNS = ("x", "y", "cos_yaw", "sin_yaw", "speed", "lateral_speed", "yaw_rate", "length", "width", "goal_x",
                "goal_y", "finished", "crashed", "at_goal", "time_remaining")
CAR_COLUMNS = ("present", "x", "y", "cos_yaw", "sin_yaw", "vx", "vy", "length", "width", "finished", "crashed",
               "same_team")
PEDESTRIAN_COLUMNS = ("present", "x", "y", "vx", "vy")
OBSTACLE_COLUMNS = ("present", "x", "y", "cos_yaw", "sin_yaw", "length", "width")
LANE_COLUMNS = ("x1", "y1", "x2", "y2", "kind")
STATE_CAR_COLUMNS = ("x", "y", "cos_yaw", "sin_yaw", "vx", "vy", "yaw_rate", "length", "width", "team", "goal_x",
                     "goal_y", "finished", "crashed", "at_goal")
STATE_PEDESTRIAN_COLUMNS = ("present", "x", "y", "vx", "vy")
STATE_OBSTACLE_COLUMNS = ("present", "x", "y")

VELOCITY_BOUND = 100.0          # m/s: no car gets near it before leaving the road (clipped anyway)
YAW_RATE_BOUND = 50.0           # rad/s: a spinning crashed car (clipped)
_FINISHED, _CRASHED, _AT_GOAL = ObjectStatus.FINISHED, ObjectStatus.CRASHED, ObjectStatus.AT_GOAL


class DrivingObservationBuilder(Protocol):
    """What ``driving_v0`` needs from an observation mode (see the module docstring)."""
    mode: str
    space: spaces.Space

    def reset(self, world: Any) -> None: ...

    def on_frame(self, index: int) -> None: ...

    def initial(self) -> list[Any]: ...

    def build(self) -> tuple[list[Any], np.ndarray]: ...

    def infos(self, index: int) -> dict[str, Any]: ...


# -- bounds ----------------------------------------------------------------------------------------------------------
def _reach(config: DrivingConfig) -> float:
    """Longest distance between two points a body can occupy (the walled area's diagonal), m."""
    m = config.map
    return math.hypot(m.width + 2 * m.boundary_margin, m.height + 2 * m.boundary_margin)


def _limits(config: DrivingConfig) -> dict[str, tuple[float, float]]:
    reach = _reach(config)
    size = max(2 * max(config.cars.half_lengths), config.obstacles.size)
    return {"pos": (-reach, reach), "vel": (-VELOCITY_BOUND, VELOCITY_BOUND), "unit": (-1.0, 1.0),
            "flag": (0.0, 1.0), "sign": (-1.0, 1.0), "size": (0.0, size),
            "yaw_rate": (-YAW_RATE_BOUND, YAW_RATE_BOUND), "time": (0.0, float(config.episode_seconds))}


_KIND = {"x": "pos", "y": "pos", "x1": "pos", "y1": "pos", "x2": "pos", "y2": "pos", "goal_x": "pos",
         "goal_y": "pos", "cos_yaw": "unit", "sin_yaw": "unit", "speed": "vel", "lateral_speed": "vel", "vx": "vel",
         "vy": "vel", "yaw_rate": "yaw_rate", "length": "size", "width": "size", "finished": "flag",
         "crashed": "flag", "at_goal": "flag", "present": "flag", "same_team": "sign", "team": "sign",
         "kind": "sign", "time_remaining": "time"}


def _bounds(config: DrivingConfig, blocks: list[tuple[tuple[str, ...], int]]) -> tuple[np.ndarray, np.ndarray]:
    limits = _limits(config)
    pairs = [limits[_KIND[c]] for columns, rows in blocks for _ in range(rows) for c in columns]
    low, high = zip(*pairs)
    return np.array(low, np.float32), np.array(high, np.float32)


@dataclass(frozen=True)
class FullLayout:
    """Row counts of the flat ``full`` vector for one config; ``split`` names its sections."""
    cars: int                   # other cars
    pedestrians: int
    obstacles: int
    lanes: int

    @classmethod
    def for_config(cls, config: DrivingConfig) -> "FullLayout":
        return cls(config.n_cars - 1, config.pedestrians.count_max, config.obstacles.count_max,
                   len(DrivingMap(config.map).lane_lines))

    @property
    def blocks(self) -> list[tuple[str, tuple[str, ...], int]]:
        return [("self", SELF_COLUMNS, 1), ("cars", CAR_COLUMNS, self.cars),
                ("pedestrians", PEDESTRIAN_COLUMNS, self.pedestrians), ("obstacles", OBSTACLE_COLUMNS, self.obstacles),
                ("lanes", LANE_COLUMNS, self.lanes)]

    @property
    def size(self) -> int:
        return sum(len(columns) * rows for _, columns, rows in self.blocks)

    def split(self, observation: np.ndarray) -> dict[str, np.ndarray]:
        """Sections of one observation (or of a batch, last axis): ``self`` (15,), the others (rows, columns)."""
        obs = np.asarray(observation)
        if obs.shape[-1] != self.size:
            raise ValueError(f"a full driving observation has {self.size} values, got {obs.shape[-1]}")
        out, at = {}, 0
        for name, columns, rows in self.blocks:
            width = len(columns) * rows
            part = obs[..., at:at + width]
            out[name] = part if name == "self" else part.reshape(*obs.shape[:-1], rows, len(columns))
            at += width
        return out


# -- ground truth as arrays -------------------------------------------------------------------------------------------
@dataclass
class _Bodies:
    """One snapshot's bodies as map-frame arrays."""
    cars: np.ndarray            # (n, 15) STATE_CAR_COLUMNS
    peds: np.ndarray            # (P, 5) STATE_PEDESTRIAN_COLUMNS, in pedestrian order (P = this episode's count)
    obstacles: np.ndarray       # (O, 3) STATE_OBSTACLE_COLUMNS
    time_remaining: float


def _bodies(snapshot: WorldSnapshot) -> _Bodies:
    cars, peds, obstacles = [], [], []
    for o in snapshot.objects:
        if o.class_id == ObjectClass.CAR:
            s = o.status
            cars.append((o.x, o.y, math.cos(o.yaw), math.sin(o.yaw), o.vx, o.vy, o.yaw_rate, o.size_x, o.size_y,
                         o.team, o.goal_x, o.goal_y, bool(s & _FINISHED), bool(s & _CRASHED), bool(s & _AT_GOAL)))
        elif o.class_id == ObjectClass.PEDESTRIAN:
            alive = not o.status & _CRASHED
            peds.append((1.0, o.x, o.y, o.vx, o.vy) if alive else (0.0, 0.0, 0.0, 0.0, 0.0))
        elif o.class_id == ObjectClass.OBSTACLE:
            obstacles.append((1.0, o.x, o.y))
    return _Bodies(np.array(cars, float).reshape(-1, len(STATE_CAR_COLUMNS)),
                   np.array(peds, float).reshape(-1, len(STATE_PEDESTRIAN_COLUMNS)),
                   np.array(obstacles, float).reshape(-1, len(STATE_OBSTACLE_COLUMNS)), snapshot.time_remaining)


def _padded(rows: np.ndarray, count: int) -> np.ndarray:
    out = np.zeros((count, rows.shape[1]))
    out[:min(count, len(rows))] = rows[:count]
    return out


class DrivingGroundTruth:
    """Ground-truth encodings of a driving world: every car's ``full`` observation and the global ``state``."""

    def __init__(self, config: DrivingConfig) -> None:
        self.config = config
        self.layout = FullLayout.for_config(config)
        lay = self.layout
        self.observation_space = spaces.Box(*_bounds(config, [(c, r) for _, c, r in lay.blocks]), dtype=np.float32)
        self._state_blocks = [(STATE_CAR_COLUMNS, config.n_cars), (STATE_PEDESTRIAN_COLUMNS, lay.pedestrians),
                              (STATE_OBSTACLE_COLUMNS, lay.obstacles), (("time_remaining",), 1)]
        self.state_space = spaces.Box(*_bounds(config, self._state_blocks), dtype=np.float32)
        lines = DrivingMap(config.map).lane_lines
        self._lines = np.array([(line.x1, line.y1, line.x2, line.y2) for line in lines], float).reshape(-1, 4)
        self._line_kind = np.array([float(line.kind) for line in lines])
        self._obstacle_size = (config.obstacles.size, config.obstacles.size)     # length, width (square)
        n = config.n_cars
        self._others_table = np.array([[j for j in range(n) if j != i] for i in range(n)], np.intp).reshape(n, n - 1)

    def state(self, snapshot: WorldSnapshot) -> np.ndarray:
        """Map-frame ground truth: cars (id order), pedestrians (index order, absent once hit), obstacles, clock."""
        b = _bodies(snapshot)
        lay = self.layout
        flat = np.concatenate((b.cars.ravel(), _padded(b.peds, lay.pedestrians).ravel(),
                               _padded(b.obstacles, lay.obstacles).ravel(), (b.time_remaining,)))
        flat = np.nan_to_num(flat, nan=0.0)
        return np.clip(flat, self.state_space.low, self.state_space.high).astype(np.float32)

    def observations(self, snapshot: WorldSnapshot) -> np.ndarray:
        """(n_cars, layout.size) float32: every car's ``full`` observation, in its own frame (all observers at
        once: each body's offset from each car, turned into that car's frame)."""
        b = _bodies(snapshot)
        lay = self.layout
        cars = b.cars
        n = len(cars)
        x, y = cars[:, 0:1], cars[:, 1:2]                   # (n, 1): broadcast over the bodies seen
        c, s = cars[:, 2:3], cars[:, 3:4]

        def to_frame(px: np.ndarray, py: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            dx, dy = px - x, py - y
            return c * dx + s * dy, c * dy - s * dx

        def rotate(vx: np.ndarray, vy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            return c * vx + s * vy, c * vy - s * vx

        speed, lateral = rotate(cars[:, 4:5], cars[:, 5:6])
        gx, gy = to_frame(cars[:, 10:11], cars[:, 11:12])
        blocks = [np.hstack((cars[:, 0:4], speed, lateral, cars[:, 6:9], gx, gy, cars[:, 12:15],
                             np.full((n, 1), b.time_remaining)))]
        # Other cars, one slot each in id order; a car at its destination has left the map (absent, zeros).
        others = self._others_table
        o = cars[others]                                    # (n, n-1, 15)
        ox, oy = to_frame(o[..., 0], o[..., 1])
        ovx, ovy = rotate(o[..., 4], o[..., 5])
        present = 1.0 - o[..., 14]
        cos_rel = c * o[..., 2] + s * o[..., 3]
        sin_rel = c * o[..., 3] - s * o[..., 2]
        same = np.where(o[..., 9] == cars[:, 9:10], 1.0, -1.0)
        rows = np.stack((present, ox, oy, cos_rel, sin_rel, ovx, ovy, o[..., 7], o[..., 8], o[..., 12], o[..., 13],
                         same), axis=-1) * present[..., None]
        blocks.append(rows.reshape(n, -1))
        # Pedestrians (the live ones) and obstacles, nearest first, zero-padded.
        peds = b.peds[b.peds[:, 0] > 0]
        px, py = to_frame(peds[:, 1], peds[:, 2])
        pvx, pvy = rotate(peds[:, 3], peds[:, 4])
        rows = np.stack((np.ones_like(px), px, py, pvx, pvy), axis=-1)
        blocks.append(_nearest_first(rows, np.hypot(px, py), lay.pedestrians).reshape(n, -1))
        q = b.obstacles
        qx, qy = to_frame(q[:, 1], q[:, 2])
        ones = np.ones_like(qx)
        rows = np.stack((ones, qx, qy, c * ones, -s * ones, self._obstacle_size[0] * ones,
                         self._obstacle_size[1] * ones), axis=-1)
        blocks.append(_nearest_first(rows, np.hypot(qx, qy), lay.obstacles).reshape(n, -1))
        l1x, l1y = to_frame(self._lines[:, 0], self._lines[:, 1])
        l2x, l2y = to_frame(self._lines[:, 2], self._lines[:, 3])
        kind = np.broadcast_to(self._line_kind, l1x.shape)
        blocks.append(np.stack((l1x, l1y, l2x, l2y, kind), axis=-1).reshape(n, -1))
        out = np.nan_to_num(np.hstack(blocks), nan=0.0)
        return np.clip(out, self.observation_space.low, self.observation_space.high).astype(np.float32)


def _nearest_first(rows: np.ndarray, distance: np.ndarray, count: int) -> np.ndarray:
    """(n, k, F) rows per observer → (n, count, F), each observer's sorted by ``distance`` (n, k), zero-padded."""
    n, k, f = rows.shape
    out = np.zeros((n, count, f))
    if k:
        order = np.argsort(distance, axis=1, kind="stable")[:, :count]
        out[:, :order.shape[1]] = np.take_along_axis(rows, order[..., None], axis=1)
    return out


# -- the modes --------------------------------------------------------------------------------------------------------
class FullObservation:
    """``observation='full'``: ground truth in each car's frame (module docstring); no perception, no reward."""
    mode = "full"

    def __init__(self, config: DrivingConfig, perception: Any = None) -> None:
        if perception is not None:
            raise ValueError("perception applies to perceived observations; observation='full' is noise-free "
                             f"ground truth (got perception={perception!r}: leave it out)")
        self.config = config
        self.ground_truth = DrivingGroundTruth(config)
        self.layout = self.ground_truth.layout
        self.space: spaces.Space = self.ground_truth.observation_space
        self.world: Any = None

    def reset(self, world: Any) -> None:
        self.world = world

    def on_frame(self, index: int) -> None:
        pass                                        # the period's end is all full mode looks at

    def initial(self) -> list[Any]:
        return self.build()[0]

    def build(self) -> tuple[list[Any], np.ndarray]:
        rows = self.ground_truth.observations(self.world.snapshot())
        return list(rows), np.zeros(len(rows))

    def infos(self, index: int) -> dict[str, Any]:
        return {}


# -- perceived modes --------------------------------------------------------------------------------------------------
EGO_BOUNDS = {"speed": "vel", "yaw_rate": "yaw_rate", "goal_x": "pos", "goal_y": "pos", "length": "size",
              "width": "size", "crashed": "flag", "finished": "flag"}
PREVIOUS_ACTION_COLUMNS = ("throttle", "brake", "steering")


def feature_bound(config: DrivingConfig) -> float:
    """The one bound (±) of every perceived feature column: the walled area's diagonal (224.7 m by default), which
    also covers speeds (±100 m/s), yaw rates and sizes. Feature rows are clipped to it."""
    return float(max(_reach(config), VELOCITY_BOUND, YAW_RATE_BOUND))


def driving_perception_params(setting: Any) -> Any:
    """A preset name (``realistic``, ``dynenv``, ``none``), a mapping ``{"preset": name, **overrides}``, ready
    ``DrivingPerceptionParams``, or None (``realistic``)."""
    from dynenv_ros.perception.driving_params import DrivingPerceptionParams, load_driving_preset
    return resolve_setting("realistic" if setting is None else setting, DrivingPerceptionParams, load_driving_preset,
                           "a driving preset name, a mapping or DrivingPerceptionParams")


class PartialObservation:
    """``observation='partial'``: what the car's sensors report (``driving/vision.py``), per vision frame of the
    period (one with the default rates) its detection rows as float32 feature rows
    (``perception.detections.FEATURE_COLUMNS``: the SELF row first, then nearest first; variable length), the ego
    values (``perception.driving_model.EGO_COLUMNS``, the SELF row's values: what the car knows of itself) per frame,
    and the previous period's action [throttle, brake, steering]. No observation reward (the driving world defines
    none); ``infos``: ``visible_objects`` (cars, pedestrians, obstacles in range and not hidden), ``seen_objects``
    (of those, reported as their own class) and ``lanes_seen``, summed over the period's frames."""
    mode = "partial"

    def __init__(self, config: DrivingConfig, perception: Any = None) -> None:
        from dynenv_ros.perception.detections import FEATURE_COLUMNS
        from dynenv_ros.perception.driving_model import EGO_COLUMNS
        self.config = config
        self.params = driving_perception_params(perception)
        self.frames = config.rates.frames_per_period
        self.bound = feature_bound(config)
        row = spaces.Box(-self.bound, self.bound, (len(FEATURE_COLUMNS),), np.float32)
        low, high = _bounds(config, [(EGO_COLUMNS, self.frames)])
        mode_space = _previous_action_space(config)
        self.space: spaces.Space = spaces.Dict({
            "detections": spaces.Tuple([spaces.Sequence(row, stack=True)] * self.frames),
            "ego": spaces.Box(low.reshape(self.frames, -1), high.reshape(self.frames, -1), dtype=np.float32),
            "previous_action": mode_space})
        self._ego_low, self._ego_high = low.reshape(self.frames, -1), high.reshape(self.frames, -1)
        self._action_low, self._action_high = mode_space.low, mode_space.high
        self.world: Any = None
        self.vision: Any = None
        self._perceptions: list[Any] = []
        n = config.n_cars
        self._counts = np.zeros((n, 3), np.int64)

    def reset(self, world: Any) -> None:
        from dynenv_ros.driving.vision import DrivingVision
        self.world = world
        if self.vision is None or self.vision.world is not world:
            self.vision = DrivingVision(world, self.params)
        else:
            self.vision.reset()
        self._perceptions = []

    def on_frame(self, index: int) -> None:
        if index == 0:
            self._perceptions = []
        self._perceptions.append(self.vision.perceive())

    def initial(self) -> list[Any]:
        """After a reset: every frame of the period shows the initial state."""
        for k in range(self.frames):
            self.on_frame(k)
        return self.build()[0]

    def _gather(self) -> tuple[list[np.ndarray], list[np.ndarray], np.ndarray, np.ndarray]:
        """The period's frames: per frame its clipped feature rows and view offsets, the ego values (n, F, 8) and the
        previous actions (n, 3), clipped to their spaces; the infos' counts updated."""
        from dynenv_ros.perception.row_kernels import clipped_features
        n, b = self.config.n_cars, self.bound
        frames = self._perceptions
        features, offsets = [], []
        ego = np.empty((n, len(frames), self._ego_low.shape[1]), np.float32)
        counts = self._counts
        counts[:] = 0
        for f, p in enumerate(frames):
            features.append(clipped_features(p.detections, b))
            offsets.append(p.offsets)
            ego[:, f] = p.ego
            counts[:, 0] += p.visible.sum(axis=1)
            counts[:, 1] += p.seen.sum(axis=1)
            counts[:, 2] += p.lanes_seen
        np.minimum(np.maximum(ego, self._ego_low[:len(frames)], out=ego), self._ego_high[:len(frames)], out=ego)
        actions = np.array([(a.throttle, a.brake, a.steering) for a in self.world.last_actions], np.float32)
        np.minimum(np.maximum(actions, self._action_low, out=actions), self._action_high, out=actions)
        return features, offsets, ego, actions

    def build(self) -> tuple[list[Any], np.ndarray]:
        n = self.config.n_cars
        features, offsets, ego, actions = self._gather()
        out = [{"detections": tuple(rows[off[i]:off[i + 1]] for rows, off in zip(features, offsets)),
                "ego": ego[i], "previous_action": actions[i]} for i in range(n)]
        return out, np.zeros(n)

    def infos(self, index: int) -> dict[str, Any]:
        c = self._counts[index]
        return {"visible_objects": int(c[0]), "seen_objects": int(c[1]), "lanes_seen": int(c[2])}


def _previous_action_space(config: DrivingConfig) -> spaces.Box:
    """[throttle −1..1, brake 0..1, steering ±max_yaw_rate rad/s] (a discrete action as the command it became)."""
    w = config.cars.max_yaw_rate
    return spaces.Box(np.array([-1.0, 0.0, -w], np.float32), np.array([1.0, 1.0, w], np.float32), dtype=np.float32)


# -- the padded layout ------------------------------------------------------------------------------------------------
# Room in the objects stream beyond every other car, pedestrian and obstacle a config can place: one near-car false
# positive per other car and the 10 false-positive trials per view of the presets (docs/driving.md).
FALSE_POSITIVE_SLOTS = 10
GAME_COLUMNS = ("seconds_remaining",)


def driving_layout_spec(config: DrivingConfig) -> Any:
    """Driving's ``envs.padded_layout.LayoutSpec``: streams ``lanes`` (SELF and LANE rows: the car's SELF row in slot
    0, then lanes nearest first) and ``objects`` (CAR, PEDESTRIAN, OBSTACLE and UNKNOWN rows, nearest first); the
    ego values as proprioception, the seconds remaining as ``game``, [throttle, brake, steering] as the previous
    action, each with ``partial``'s bounds; features within ±``feature_bound(config)``."""
    from dynenv_ros.envs.padded_layout import LayoutSpec, StreamSpec
    from dynenv_ros.perception.driving_model import EGO_COLUMNS
    ego_low, ego_high = _bounds(config, [(EGO_COLUMNS, 1)])
    actions = _previous_action_space(config)
    C = ObjectClass
    return LayoutSpec("driving", (StreamSpec("lanes", "lane_mask", (int(C.SELF), int(C.LANE))),
                                  StreamSpec("objects", "object_mask", (int(C.CAR), int(C.PEDESTRIAN), int(C.OBSTACLE),
                                                                        int(C.UNKNOWN)))),
                      feature_bound(config), EGO_COLUMNS, ego_low, ego_high, GAME_COLUMNS, (0.0,),
                      (float(config.episode_seconds),), PREVIOUS_ACTION_COLUMNS, actions.low, actions.high)


def default_maxima(config: DrivingConfig) -> tuple[int, int]:
    """(lanes, objects) rows per frame that hold every report the presets can make: the SELF row and each of the map's
    lanes (``driving.vision.map_lanes``: 11 by default); every other car, pedestrian and obstacle the config can place,
    a near-car false positive per other car and ``FALSE_POSITIVE_SLOTS`` (2 cars: 52; 10 cars: 68)."""
    from dynenv_ros.driving.vision import map_lanes
    lanes = 1 + len(map_lanes(DrivingMap(config.map))[0])
    objects = 2 * (config.n_cars - 1) + config.pedestrians.count_max + config.obstacles.count_max
    return lanes, objects + FALSE_POSITIVE_SLOTS


def driving_layout(config: DrivingConfig, max_lanes: int | None = None, max_objects: int | None = None) -> Any:
    """The ``PaddedLayout`` of a config: one frame per vision frame of the period, ``default_maxima`` unless given."""
    from dynenv_ros.envs.padded_layout import PaddedLayout
    lanes, objects = default_maxima(config)
    return PaddedLayout(config.rates.frames_per_period, lanes if max_lanes is None else max_lanes,
                        objects if max_objects is None else max_objects, driving_layout_spec(config))


class PaddedObservation(PartialObservation):
    """``observation='padded'``: ``partial``'s rows in the fixed-shape layout of ``envs.padded_layout`` (keys
    ``lanes``, ``lane_mask``, ``objects``, ``object_mask``, ``proprioception`` (F, 8) the ego values, ``game`` (1,)
    the seconds remaining at the period's last frame, ``previous_action`` (3,)), packed by ``PaddedLayout.pack_rows``.
    Options ``max_lanes``, ``max_objects`` (default ``default_maxima``); rows beyond them are dropped farthest first
    and counted in ``infos[agent]['dropped_detections']`` (besides ``partial``'s infos)."""
    mode = "padded"

    def __init__(self, config: DrivingConfig, perception: Any = None, max_lanes: int | None = None,
                 max_objects: int | None = None) -> None:
        super().__init__(config, perception)
        self.layout = driving_layout(config, max_lanes, max_objects)
        self.space = self.layout.space()
        n = config.n_cars
        self.dropped_rows = np.zeros(n, np.int64)
        self._time_remaining = 0.0
        self._views: dict[int, tuple[np.ndarray, np.ndarray]] = {}   # per frame count: each view's car, frame
        self.arrays: dict[str, np.ndarray] = {}

    def on_frame(self, index: int) -> None:
        super().on_frame(index)
        self._time_remaining = self.world.time_remaining

    def build_padded(self, out: dict[str, np.ndarray] | None = None) -> np.ndarray:
        """Fill ``out`` (``layout.empty(n_cars)``, or new arrays kept in ``self.arrays``) without per-car dicts and
        return the observation reward per car (zeros: the driving world defines none). For vectorised batches."""
        n = self.config.n_cars
        features, offsets, ego, actions = self._gather()
        frames = len(features)
        if frames not in self._views:
            views = np.arange(frames * n)
            self._views[frames] = (views % n, views // n)
        bases = np.cumsum([0] + [len(rows) for rows in features[:-1]])
        joined = np.concatenate([off[:-1] + base for off, base in zip(offsets, bases)]
                                + [np.array([bases[-1] + offsets[-1][-1]])])
        arrays = self.layout.empty(n) if out is None else out
        self.dropped_rows = self.layout.pack_rows(np.concatenate(features), joined, *self._views[frames], arrays,
                                                  clear=out is not None).reshape(frames, n).sum(axis=0)
        arrays["proprioception"][:, :frames] = ego
        arrays["game"][:, 0] = self._time_remaining
        arrays["previous_action"][:] = actions
        self.arrays = arrays
        return np.zeros(n)

    def initial_padded(self, out: dict[str, np.ndarray] | None = None) -> None:
        for k in range(self.frames):
            self.on_frame(k)
        self.build_padded(out)

    def build(self) -> tuple[list[Any], np.ndarray]:
        rewards = self.build_padded()
        return [{key: value[i] for key, value in self.arrays.items()} for i in range(self.config.n_cars)], rewards

    def infos(self, index: int) -> dict[str, Any]:
        return {**super().infos(index), "dropped_detections": int(self.dropped_rows[index])}


ObservationFactory = Callable[..., DrivingObservationBuilder]
OBSERVATION_BUILDERS: dict[str, ObservationFactory] = {"full": FullObservation,
                                                      "partial": PartialObservation,
                                                      "padded": PaddedObservation}


def register_observation(name: str, factory: ObservationFactory) -> None:
    """Add an observation mode: ``factory(config, perception=…, **options)`` → a ``DrivingObservationBuilder``."""
    if not isinstance(name, str) or not name:
        raise ValueError(f"an observation mode needs a non-empty name, got {name!r}")
    OBSERVATION_BUILDERS[name] = factory


def observation_builder(mode: Any, config: DrivingConfig, perception: Any = None,
                        options: Mapping[str, Any] | None = None) -> DrivingObservationBuilder:
    """The builder of an observation mode; an unknown mode is refused with the valid ones listed."""
    if not isinstance(mode, str) or mode not in OBSERVATION_BUILDERS:
        raise ValueError(f"observation must be one of {tuple(OBSERVATION_BUILDERS)}, got {mode!r}")
    if options is not None and not isinstance(options, Mapping):
        raise ValueError(f"observation_options must be a mapping or None, got {type(options).__name__}")
    try:
        return OBSERVATION_BUILDERS[mode](config, perception=perception, **dict(options or {}))
    except TypeError as exc:
        if "unexpected keyword argument" not in str(exc):
            raise
        raise ValueError(f"observation={mode!r} does not take that option: {exc}") from None


__all__ = ["DrivingObservationBuilder", "FullObservation", "PartialObservation", "PaddedObservation",
           "driving_layout_spec", "driving_layout", "default_maxima", "FALSE_POSITIVE_SLOTS", "GAME_COLUMNS",
           "driving_perception_params",
           "feature_bound", "PREVIOUS_ACTION_COLUMNS", "FullLayout", "DrivingGroundTruth", "OBSERVATION_BUILDERS",
           "register_observation", "observation_builder", "SELF_COLUMNS", "CAR_COLUMNS", "PEDESTRIAN_COLUMNS",
           "OBSTACLE_COLUMNS", "LANE_COLUMNS", "STATE_CAR_COLUMNS", "STATE_PEDESTRIAN_COLUMNS",
           "STATE_OBSTACLE_COLUMNS"]
