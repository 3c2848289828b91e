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

All float32 Boxes. Rows beyond a stream's maximum are dropped farthest first (counted); the default maxima (40
landmarks; the ball, every other robot and 4 more objects) held every detection of every frame in 1,000 periods
of random play under each preset (docs/perception.md). This module is the single definition: the
PettingZoo env (``observation="padded"``), the vectorised batch, the agent's input adapter and the policy node all
pack with ``pack_rows``, so the same detections give the same arrays everywhere.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from gymnasium import spaces

from dynenv_ros.core.object_classes import ObjectClass
from dynenv_ros.perception.detections import FEATURE_COLUMNS

FEATURES = len(FEATURE_COLUMNS)
FEATURE_BOUND = 50.0
LANDMARK_CLASSES = (ObjectClass.GOALPOST, ObjectClass.PENALTY_CROSS, ObjectClass.LINE_CROSSING,
                    ObjectClass.FIELD_LINE, ObjectClass.CENTER_CIRCLE)
OBJECT_CLASSES = (ObjectClass.BALL, ObjectClass.ROBOT)
PROPRIOCEPTION_COLUMNS = ("head_yaw", "fallen", "penalized", "kicking")
# ball_owner: +1 own team owns the ball (kick-off or set play), -1 the opponents do, 0 free ball; seconds in SI.
GAME_COLUMNS = ("ball_owner", "ball_owner_seconds", "game_seconds_remaining")
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

# Stream of each class id: 0 landmarks, 1 objects, -1 neither.
STREAM_OF_CLASS = np.full(256, -1, np.int8)
STREAM_OF_CLASS[list(LANDMARK_CLASSES)] = 0
STREAM_OF_CLASS[list(OBJECT_CLASSES)] = 1


@dataclass(frozen=True)
class PaddedLayout:
    frames: int = 5
    max_landmarks: int = DEFAULT_MAX_LANDMARKS
    max_objects: int = 2 * 2 + EXTRA_OBJECT_SLOTS

    def __post_init__(self) -> None:
        for name in ("frames", "max_landmarks", "max_objects"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
                raise ValueError(f"PaddedLayout.{name} must be a positive integer, got {value!r}")

    @classmethod
    def for_players(cls, players_per_team: int, frames: int, max_landmarks: int | None = None,
                    max_objects: int | None = None) -> "PaddedLayout":
        """Default maxima: 40 landmarks, and the ball + every other robot + 4 false positives."""
        return cls(frames, DEFAULT_MAX_LANDMARKS if max_landmarks is None else max_landmarks,
                   2 * players_per_team + EXTRA_OBJECT_SLOTS if max_objects is None else max_objects)

    @classmethod
    def fitting(cls, frames_per_robot: list[list[np.ndarray]], max_landmarks: int | None = None,
                max_objects: int | None = None) -> "PaddedLayout":
        """The smallest layout that holds these rows (per robot, per frame a (k, 19) array), or the given maxima
        where set (a fixed-shape runtime's)."""
        longest = np.zeros(2, np.int64)
        for frames in frames_per_robot:
            for rows in frames:
                stream = STREAM_OF_CLASS[np.asarray(rows)[:, 0].astype(np.int64) & 255]
                longest = np.maximum(longest, np.bincount(stream[stream >= 0], minlength=2))
        return cls(max([len(frames) for frames in frames_per_robot] + [1]),
                   max_landmarks or max(1, int(longest[0])), max_objects or max(1, int(longest[1])))

    def shapes(self) -> dict[str, tuple[int, ...]]:
        F, L, O = self.frames, self.max_landmarks, self.max_objects
        return {"landmarks": (F, L, FEATURES), "landmark_mask": (F, L), "objects": (F, O, FEATURES),
                "object_mask": (F, O), "proprioception": (F, len(PROPRIOCEPTION_COLUMNS)),
                "game": (len(GAME_COLUMNS),), "previous_action": (len(ACTION_COLUMNS),)}

    def space(self, head_max: float = np.pi) -> spaces.Dict:
        shapes = self.shapes()
        bounds = {"landmarks": FEATURE_BOUND, "objects": FEATURE_BOUND, "landmark_mask": None,
                  "object_mask": None, "proprioception": np.pi}
        out = {}
        for key in KEYS:
            if key in ("landmark_mask", "object_mask"):
                out[key] = spaces.Box(0.0, 1.0, shapes[key], np.float32)
            elif key == "game":
                out[key] = spaces.Box(np.array([-1.0, 0.0, 0.0], np.float32),
                                      np.array([1.0, GAME_BOUND, GAME_BOUND], np.float32), dtype=np.float32)
            elif key == "previous_action":
                out[key] = spaces.Box(np.array([0, 0, 0, -head_max], np.float32),
                                      np.array([4, 2, 2, head_max], np.float32), dtype=np.float32)
            else:
                out[key] = spaces.Box(-bounds[key], bounds[key], shapes[key], np.float32)
        return spaces.Dict(out)

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
        stream = STREAM_OF_CLASS[features[:, 0].astype(np.int64) & 255]
        records = features.view(_ROW)[:, 0]        # whole rows as single items: one copy per row, not per column
        dropped = np.zeros(V, np.int64)
        for s, (rows_key, mask_key, limit) in enumerate((("landmarks", "landmark_mask", self.max_landmarks),
                                                         ("objects", "object_mask", self.max_objects))):
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


_ROW = np.dtype((np.void, FEATURES * 4))     # one float32 feature row as an opaque item


def clamp_features(features: np.ndarray) -> np.ndarray:
    """Feature rows within the space's bounds (a far false positive cannot leave the Box)."""
    return np.clip(features, -FEATURE_BOUND, FEATURE_BOUND)


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
