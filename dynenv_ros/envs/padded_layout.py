"""The fixed-shape observation: one robot's motion period as arrays every RL tool can batch.

Per robot, for the F vision frames of a motion period:

| key | shape | what |
|---|---|---|
| ``landmarks`` | (F, L, 19) | detection rows (``perception.detections.FEATURE_COLUMNS``) of goalposts, penalty marks, line crossings, field lines and the centre circle, nearest first, zero-padded |
| ``landmark_mask`` | (F, L) | 1 where a row holds a detection, 0 where padded |
| ``objects`` | (F, O, 19) | rows of balls and robots, nearest first, zero-padded |
| ``object_mask`` | (F, O) | 1 / 0 as above |
| ``proprioception`` | (F, 4) | ``PROPRIOCEPTION_COLUMNS`` per frame: what the robot knows of itself |
| ``game`` | (3,) | ``GAME_COLUMNS``: what the GameController broadcasts, at the period's last frame |
| ``previous_action`` | (4,) | ``ACTION_COLUMNS``: the action the robot took last period (zeros after a reset) |
| ``pose_estimate`` | (7,) | only with ``PaddedLayout(pose=True)`` (soccer's ``localization="estimate"``): the self-localization estimate at the period's last frame, in the robot's team frame (``envs.pose_features``: columns and bounds) |

All float32 Boxes. The layout is one definition for both scenarios: a ``LayoutSpec`` names a scenario's two
detection streams (their keys and classes: the static one first, the dynamic one second), its proprioception, game
and previous-action columns with their bounds, and its feature bound. ``SOCCER`` (this module) gives the table above
exactly; driving's (``envs.driving_observations.driving_layout_spec``) has the streams ``lanes`` (the car's SELF row
in slot 0, then lane rows) and ``objects`` (cars, pedestrians, obstacles), the ego values as proprioception, the
seconds remaining as ``game`` and [throttle, brake, steering] as the previous action (docs/driving.md). The rest
(``pack_rows``, ``fitting``, ``pack_frames``, ``empty``) is scenario-neutral and reads the spec. The first stream's
maximum is ``max_landmarks``, the second's ``max_objects``, whatever the scenario calls the streams.

Soccer: rows beyond a stream's maximum are dropped farthest first (counted); the default maxima (40
landmarks; the ball, every other robot and 4 more objects) held every detection of every frame in 1,000 periods
of random play under each preset (docs/perception.md). This module is the single definition: the
PettingZoo env (``observation="padded"``), the vectorised batch, the agent's input adapter and the policy node all
pack with ``pack_rows``, so the same detections give the same arrays everywhere.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from gymnasium import spaces

from dynenv_ros.core.object_classes import ObjectClass
from dynenv_ros.envs.pose_features import POSE_COLUMNS, POSE_HIGH, POSE_KEY, POSE_LOW
from dynenv_ros.perception.detections import FEATURE_COLUMNS
from dynenv_ros.soccer.observation_columns import GAME_COLUMNS as GAME_COLUMNS
from dynenv_ros.soccer.observation_columns import PROPRIOCEPTION_COLUMNS as PROPRIOCEPTION_COLUMNS

FEATURES = len(FEATURE_COLUMNS)
FEATURE_BOUND = 50.0
LANDMARK_CLASSES = (ObjectClass.GOALPOST, ObjectClass.PENALTY_CROSS, ObjectClass.LINE_CROSSING,
                    ObjectClass.FIELD_LINE, ObjectClass.CENTER_CIRCLE)
OBJECT_CLASSES = (ObjectClass.BALL, ObjectClass.ROBOT)
# head_yaw_delta in rad per period, whatever the head mode (a discrete index is converted).
ACTION_COLUMNS = ("walk", "turn", "kick", "head_yaw_delta")
KEYS = ("landmarks", "landmark_mask", "objects", "object_mask", "proprioception", "game", "previous_action")
DEFAULT_MAX_LANDMARKS = 40
EXTRA_OBJECT_SLOTS = 4       # room for false positives beyond the ball and the other robots
GAME_BOUND = 1000.0          # s; longer than any configurable episode
# Bounds on what any runtime packs (an ONNX file's fixed shapes, a message's frames): 64 frames per period is a
# 30 Hz camera with a 2 s motion period (the defaults give 5); 256 slots per frame is over 6x the maxima above
# (40 landmarks, 14 objects in 5v5), which held every detection of 1,000 periods of random play. They bound the
# arrays a node allocates per decision (10 robots x 64 frames x 256 slots x 19 floats: 12 MB per stream).
MAX_FRAMES = 64
MAX_SLOTS = 256


@dataclass(frozen=True)
class StreamSpec:
    """One detection stream: its rows' key, its mask's key and the classes whose rows it holds."""
    key: str
    mask: str
    classes: tuple[int, ...]


def _floats(values) -> tuple[float, ...]:
    return tuple(float(v) for v in values)


@dataclass(frozen=True)
class LayoutSpec:
    """What a scenario puts in the padded layout (module docstring). ``streams``: (static, dynamic); every column
    tuple comes with its per-column ``low`` / ``high`` bounds; ``feature_bound``: ± the bound of every detection
    feature (rows are clipped to it). Soccer's previous-action head bound is set per config (``space(head_max)``)."""
    scenario: str
    streams: tuple[StreamSpec, StreamSpec]
    feature_bound: float
    proprioception_columns: tuple[str, ...]
    proprioception_low: tuple[float, ...]
    proprioception_high: tuple[float, ...]
    game_columns: tuple[str, ...]
    game_low: tuple[float, ...]
    game_high: tuple[float, ...]
    action_columns: tuple[str, ...]
    action_low: tuple[float, ...]
    action_high: tuple[float, ...]
    pose_estimate: bool = False    # the layout may also carry the self-localization estimate (PaddedLayout.pose)
    # Stream of each class id: 0 the first stream, 1 the second, -1 neither (derived from ``streams``).
    stream_of_class: np.ndarray = field(init=False, repr=False, compare=False, hash=False)

    def __post_init__(self) -> None:
        for name in ("proprioception_low", "proprioception_high", "game_low", "game_high", "action_low",
                     "action_high"):
            object.__setattr__(self, name, _floats(getattr(self, name)))
        object.__setattr__(self, "feature_bound", float(self.feature_bound))
        if len(self.streams) != 2:
            raise ValueError(f"a layout has two streams (static, dynamic), got {len(self.streams)}")
        keys = self.keys
        if len(set(keys)) != len(keys):
            raise ValueError(f"LayoutSpec {self.scenario!r}: repeated keys in {keys}")
        for columns, low, high in ((self.proprioception_columns, self.proprioception_low, self.proprioception_high),
                                   (self.game_columns, self.game_low, self.game_high),
                                   (self.action_columns, self.action_low, self.action_high)):
            if not len(columns) == len(low) == len(high) or any(a > b for a, b in zip(low, high)):
                raise ValueError(f"LayoutSpec {self.scenario!r}: bounds of {columns} do not match them")
        table = np.full(256, -1, np.int8)
        for s, stream in enumerate(self.streams):
            if (table[list(stream.classes)] >= 0).any():
                raise ValueError(f"LayoutSpec {self.scenario!r}: a class in two streams")
            table[list(stream.classes)] = s
        table.flags.writeable = False
        object.__setattr__(self, "stream_of_class", table)

    @property
    def keys(self) -> tuple[str, ...]:
        """The observation's keys, in order: each stream's rows and mask, proprioception, game, previous_action."""
        (a, b) = self.streams
        return (a.key, a.mask, b.key, b.mask, "proprioception", "game", "previous_action")


SOCCER = LayoutSpec(
    "soccer", (StreamSpec("landmarks", "landmark_mask", tuple(int(c) for c in LANDMARK_CLASSES)),
               StreamSpec("objects", "object_mask", tuple(int(c) for c in OBJECT_CLASSES))),
    FEATURE_BOUND, PROPRIOCEPTION_COLUMNS, (-math.pi,) * 4, (math.pi,) * 4,
    GAME_COLUMNS, (-1.0, 0.0, 0.0), (1.0, GAME_BOUND, GAME_BOUND),
    ACTION_COLUMNS, (0.0, 0.0, 0.0, -math.pi), (4.0, 2.0, 2.0, math.pi), pose_estimate=True)
STREAM_OF_CLASS = SOCCER.stream_of_class     # soccer's: 0 landmarks, 1 objects, -1 neither


@dataclass(frozen=True)
class PaddedLayout:
    frames: int = 5
    max_landmarks: int = DEFAULT_MAX_LANDMARKS      # the first (static) stream's maximum
    max_objects: int = 2 * 2 + EXTRA_OBJECT_SLOTS   # the second (dynamic) stream's maximum
    spec: LayoutSpec = SOCCER
    pose: bool = False          # the ``pose_estimate`` key too (``envs.pose_features``; a spec with ``pose_estimate``:
                                # soccer's), last in ``keys``

    def __post_init__(self) -> None:
        for name in ("frames", "max_landmarks", "max_objects"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
                raise ValueError(f"PaddedLayout.{name} must be a positive integer, got {value!r}")
        if not isinstance(self.spec, LayoutSpec):
            raise ValueError(f"PaddedLayout.spec must be a LayoutSpec, got {self.spec!r}")
        if not isinstance(self.pose, bool):
            raise ValueError(f"PaddedLayout.pose must be True or False, got {self.pose!r}")
        if self.pose and not self.spec.pose_estimate:
            raise ValueError(f"PaddedLayout.pose: the pose estimate is soccer's, not {self.spec.scenario!r}'s")

    @property
    def keys(self) -> tuple[str, ...]:
        """The spec's keys, then ``pose_estimate`` when ``pose``."""
        return self.spec.keys + ((POSE_KEY,) if self.pose else ())

    @property
    def maxima(self) -> tuple[int, int]:
        """(first stream's, second stream's) maximum rows per frame."""
        return self.max_landmarks, self.max_objects

    @classmethod
    def for_players(cls, players_per_team: int, frames: int, max_landmarks: int | None = None,
                    max_objects: int | None = None, pose: bool = False) -> "PaddedLayout":
        """Default maxima: 40 landmarks, and the ball + every other robot + 4 false positives."""
        return cls(frames, DEFAULT_MAX_LANDMARKS if max_landmarks is None else max_landmarks,
                   2 * players_per_team + EXTRA_OBJECT_SLOTS if max_objects is None else max_objects, pose=pose)

    @classmethod
    def fitting(cls, frames_per_robot: list[list[np.ndarray]], max_landmarks: int | None = None,
                max_objects: int | None = None, spec: LayoutSpec = SOCCER) -> "PaddedLayout":
        """The smallest layout that holds these rows (per robot, per frame a (k, 19) array), or the given maxima
        where set (a fixed-shape runtime's)."""
        longest = np.zeros(2, np.int64)
        for frames in frames_per_robot:
            for rows in frames:
                stream = spec.stream_of_class[np.asarray(rows)[:, 0].astype(np.int64) & 255]
                longest = np.maximum(longest, np.bincount(stream[stream >= 0], minlength=2))
        return cls(max([len(frames) for frames in frames_per_robot] + [1]),
                   max_landmarks or max(1, int(longest[0])), max_objects or max(1, int(longest[1])), spec)

    def shapes(self) -> dict[str, tuple[int, ...]]:
        F, spec = self.frames, self.spec
        (a, b) = spec.streams
        shapes = {a.key: (F, self.max_landmarks, FEATURES), a.mask: (F, self.max_landmarks),
                  b.key: (F, self.max_objects, FEATURES), b.mask: (F, self.max_objects),
                  "proprioception": (F, len(spec.proprioception_columns)),
                  "game": (len(spec.game_columns),), "previous_action": (len(spec.action_columns),)}
        if self.pose:
            shapes[POSE_KEY] = (len(POSE_COLUMNS),)
        return shapes

    def space(self, head_max: float | None = None) -> spaces.Dict:
        """The observation space. ``head_max`` (soccer only; default π): the head turn's bound, rad per period."""
        spec, shapes = self.spec, self.shapes()
        action_low, action_high = np.array(spec.action_low, np.float32), np.array(spec.action_high, np.float32)
        if head_max is not None:
            if "head_yaw_delta" not in spec.action_columns:
                raise ValueError(f"head_max applies to soccer's layout, not {spec.scenario!r}'s")
            at = spec.action_columns.index("head_yaw_delta")
            action_low[at], action_high[at] = -head_max, head_max
        proprio_low = np.broadcast_to(np.array(spec.proprioception_low, np.float32), shapes["proprioception"])
        proprio_high = np.broadcast_to(np.array(spec.proprioception_high, np.float32), shapes["proprioception"])
        out = {}
        for stream in spec.streams:
            out[stream.key] = spaces.Box(-spec.feature_bound, spec.feature_bound, shapes[stream.key], np.float32)
            out[stream.mask] = spaces.Box(0.0, 1.0, shapes[stream.mask], np.float32)
        out["proprioception"] = spaces.Box(proprio_low.copy(), proprio_high.copy(), dtype=np.float32)
        out["game"] = spaces.Box(np.array(spec.game_low, np.float32), np.array(spec.game_high, np.float32),
                                 dtype=np.float32)
        out["previous_action"] = spaces.Box(action_low, action_high, dtype=np.float32)
        if self.pose:
            out[POSE_KEY] = pose_space()
        return spaces.Dict({key: out[key] for key in self.keys})

    def empty(self, *batch: int) -> dict[str, np.ndarray]:
        """Zeroed arrays with leading ``batch`` axes (e.g. ``empty(E, A)``)."""
        return {key: np.zeros(batch + shape, np.float32) for key, shape in self.shapes().items()}

    def pack_rows(self, features: np.ndarray, offsets: np.ndarray, robot_of_view: np.ndarray,
                  frame_of_view: np.ndarray, out: dict[str, np.ndarray], clear: bool = True) -> np.ndarray:
        """Scatter detection rows into ``out`` (arrays with a leading robot axis, as from ``empty(robots)``).

        ``features`` (R, 19) holds the rows of V views one view after another (``offsets`` (V+1,)), each view's
        rows nearest first; view v is robot ``robot_of_view[v]`` at frame ``frame_of_view[v]``. Detection arrays
        and masks of the touched (robot, frame) pairs are overwritten (``clear=False``: ``out`` is known to be
        zeroed already). Returns (V,) rows dropped per view."""
        V = len(offsets) - 1
        view = np.arange(V).repeat(offsets[1:] - offsets[:-1])
        robot_of_view, frame_of_view = np.asarray(robot_of_view), np.asarray(frame_of_view)
        features = np.ascontiguousarray(features, np.float32)
        stream = self.spec.stream_of_class[features[:, 0].astype(np.int64) & 255]
        records = features.view(_ROW)[:, 0]        # whole rows as single items: one copy per row, not per column
        dropped = np.zeros(V, np.int64)
        for s, (spec, limit) in enumerate(zip(self.spec.streams, self.maxima)):
            rows_key, mask_key = spec.key, spec.mask
            rows_out, mask_out = out[rows_key], out[mask_key]
            if rows_out.dtype != np.float32:
                raise TypeError(f"pack_rows: out[{rows_key!r}] must be float32 (as from empty()), got {rows_out.dtype}")
            if clear:
                rows_out[robot_of_view, frame_of_view] = 0.0
                mask_out[robot_of_view, frame_of_view] = 0.0
            chosen = (stream == s).nonzero()[0]
            v = view[chosen]
            per_view = np.bincount(v, minlength=V)
            rank = np.arange(len(v)) - (per_view.cumsum() - per_view)[v]   # rows are grouped by view
            if per_view.max(initial=0) > limit:                 # rows beyond the maximum (the farthest): dropped
                kept = (rank < limit).nonzero()[0]
                chosen, v, rank = chosen[kept], v[kept], rank[kept]
                dropped += np.maximum(per_view - limit, 0)
            at = (robot_of_view[v], frame_of_view[v], rank)
            rows_out.view(_ROW)[..., 0][at] = records[chosen]
            mask_out[at] = 1.0
        return dropped


def pose_space() -> spaces.Box:
    """The ``pose_estimate`` Box: (7,) float32 within ``POSE_LOW`` / ``POSE_HIGH``."""
    return spaces.Box(np.array(POSE_LOW, np.float32), np.array(POSE_HIGH, np.float32), dtype=np.float32)


_ROW = np.dtype((np.void, FEATURES * 4))     # one float32 feature row as an opaque item


def clamp_features(features: np.ndarray, bound: float = FEATURE_BOUND) -> np.ndarray:
    """Feature rows within the space's bounds (a far false positive cannot leave the Box); ``bound``: the
    layout's ``spec.feature_bound`` (soccer's by default)."""
    return np.clip(features, -bound, bound)


def pack_frames(layout: PaddedLayout, frames_per_robot: list[list[np.ndarray]]) -> tuple[dict[str, np.ndarray],
                                                                                         np.ndarray]:
    """Variable-length rows (per robot, per frame a (k, 19) array) → the padded arrays (robots leading), and
    the rows dropped per (robot, frame). Frames beyond ``layout.frames`` are refused."""
    robots = len(frames_per_robot)
    out = layout.empty(robots)
    blocks, robot_of_view, frame_of_view = [], [], []
    for r, frames in enumerate(frames_per_robot):
        if len(frames) > layout.frames:
            raise ValueError(f"{len(frames)} frames given, the layout holds {layout.frames}")
        for k, rows in enumerate(frames):
            blocks.append(np.asarray(rows, np.float32).reshape(-1, FEATURES))
            robot_of_view.append(r)
            frame_of_view.append(k)
    offsets = np.zeros(len(blocks) + 1, np.int64)
    np.cumsum([len(b) for b in blocks], out=offsets[1:])
    features = np.concatenate(blocks) if blocks else np.zeros((0, FEATURES), np.float32)
    dropped = layout.pack_rows(features, offsets, np.array(robot_of_view, np.int64),
                               np.array(frame_of_view, np.int64), out)
    per_frame = np.zeros((robots, layout.frames), np.int64)
    per_frame[robot_of_view, frame_of_view] = dropped
    return out, per_frame
