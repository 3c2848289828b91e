"""One vision frame's detections as a numpy structured array, field for field the content of Detection.msg.

Two extra columns never leave the simulator (they are not in the message): ``true_id`` (the world object a
detection comes from, -1 for a false positive) and ``true_class`` (its real class, so confusions can be scored).
The camera frame is REP 103 body convention: x along the gaze, y left; metres and radians.
"""
from __future__ import annotations

import numpy as np

DETECTION_DTYPE = np.dtype([
    ("class_id", np.uint8),
    ("x", np.float32), ("y", np.float32),           # position (z is 0: everything lies on the ground plane)
    ("yaw", np.float32),                             # NaN where undefined
    ("size_x", np.float32), ("size_y", np.float32),
    ("confidence", np.float32),
    ("team", np.int8),                               # TeamRelation: +1 own, -1 opponent, 0 unknown
    ("subtype", np.uint8),
    ("fallen", np.bool_), ("penalized", np.bool_),
    ("line_start_x", np.float32), ("line_start_y", np.float32),
    ("line_end_x", np.float32), ("line_end_y", np.float32),
    ("sighting", np.uint8),                          # Sighting bit mask
    ("true_id", np.int32),                           # simulator only: source object, -1 = false positive
    ("true_class", np.uint8),                        # simulator only: the source's real class (0 for FPs)
])

# Columns of the flat float32 feature rows handed to learners (``as_features``), in this order.
FEATURE_COLUMNS = ("class_id", "x", "y", "cos_yaw", "sin_yaw", "size_x", "size_y", "confidence", "team", "subtype",
                   "fallen", "penalized", "line_start_x", "line_start_y", "line_end_x", "line_end_y", "distant",
                   "partial", "nearby")


def empty(count: int = 0) -> np.ndarray:
    """``count`` zeroed detections (yaw NaN, true_id -1)."""
    out = np.zeros(count, DETECTION_DTYPE)
    out["yaw"] = np.nan
    out["true_id"] = -1
    return out


def rows_from_messages(detections, true_id: int = -2) -> np.ndarray:
    """Detection messages (rclpy or rosbags: attributes only) → rows. A message carries only what the robot
    reported, so ``true_id`` is a placeholder (-2 by default: neither a false positive nor a known object)."""
    rows = empty(len(detections))
    for i, d in enumerate(detections):
        rows[i] = (d.class_id, d.position.x, d.position.y, d.yaw, d.size_x, d.size_y, d.confidence, d.team,
                   d.subtype, d.fallen, d.penalized, d.line_start.x, d.line_start.y, d.line_end.x, d.line_end.y,
                   getattr(d, "sighting", 0), true_id, 0)      # (a bag older than the sighting bits: 0)
    return rows


def as_features(detections: np.ndarray) -> np.ndarray:
    """(k, len(FEATURE_COLUMNS)) float32 rows: yaw as cos/sin (0, 0 where undefined), sighting bits split out."""
    d = detections
    out = np.empty((len(d), len(FEATURE_COLUMNS)), np.float32)
    yaw = d["yaw"]
    defined = np.isfinite(yaw)
    safe = np.where(defined, yaw, 0.0)
    out[:, 3] = np.where(defined, np.cos(safe), 0.0)
    out[:, 4] = np.where(defined, np.sin(safe), 0.0)
    for column, name in _DIRECT:
        out[:, column] = d[name]
    s = d["sighting"]
    out[:, 16] = (s & 1) > 0
    out[:, 17] = (s & 2) > 0
    out[:, 18] = (s & 4) > 0
    return out


_DIRECT = [(i, name) for i, name in enumerate(FEATURE_COLUMNS) if name in DETECTION_DTYPE.names]
