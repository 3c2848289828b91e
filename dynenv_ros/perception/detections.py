"""One vision frame's detections as a numpy structured array, field for field the content of Detection.msg.

Two extra columns never leave the simulator (they are not in the message): ``true_id`` (the world object a
detection comes from, -1 for a false positive) and ``true_class`` (its real class, so confusions can be scored).
The camera frame is REP 103 body convention: x along the gaze, y left; metres and radians.
"""
from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any, cast

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


def rows_from_messages(detections: Sequence[Any], true_id: int = -2) -> np.ndarray:
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
    d = np.ascontiguousarray(detections)
    out = np.empty((len(d), len(FEATURE_COLUMNS)), np.float32)
    yaw = d["yaw"]
    defined = np.isfinite(yaw).nonzero()[0]
    # cos/sin of the defined yaws only (gathered, contiguous), the rest (0, 0): a masked multiply over the
    # strided pair of columns costs more than the trigonometry.
    out[:, 3:5] = 0.0
    some = yaw[defined]
    out[defined, 3] = np.cos(some)
    out[defined, 4] = np.sin(some)
    # Runs of columns that are runs of fields too, copied a run at a time through a view of the records.
    runs = d.view(_RUNS)
    out[:, 0] = d["class_id"]
    out[:, 1:3] = runs["position"]
    out[:, 5:8] = runs["size_confidence"]
    out[:, 8] = d["team"]
    out[:, 9:12] = runs["subtype_flags"]
    out[:, 12:16] = runs["line"]
    out[:, 16:19] = _SIGHTING_BITS[d["sighting"]]                   # distant, partial, nearby
    return out


def _runs(runs: dict[str, tuple[str, int]]) -> np.dtype:
    """A dtype overlaying the record with runs of consecutive same-typed fields, each as one sub-array, so a run
    of feature columns is copied with one numpy call. Refuses a run that is not consecutive fields of one type."""
    names, formats, offsets = [], [], []
    record_names = cast(tuple[str, ...], DETECTION_DTYPE.names)
    record_fields = cast(Mapping[str, tuple[np.dtype[Any], int]], DETECTION_DTYPE.fields)
    for name, (first, count) in runs.items():
        at = record_names.index(first)
        fields = [record_fields[f] for f in record_names[at:at + count]]
        size = fields[0][0].itemsize
        if len({f[0].itemsize for f in fields}) != 1 or any(f[1] != fields[0][1] + i * size
                                                            for i, f in enumerate(fields)):
            raise AssertionError(f"{name}: fields {record_names[at:at + count]} are not one run")
        names.append(name)
        formats.append((fields[0][0] if fields[0][0].kind == "f" else np.dtype("u1"), (count,)))
        offsets.append(fields[0][1])
    return np.dtype({"names": names, "formats": formats, "offsets": offsets, "itemsize": DETECTION_DTYPE.itemsize})


# x y | size_x size_y confidence | subtype fallen penalized (bytes: 0/1 flags, an unsigned subtype) | line ends
_RUNS = _runs({"position": ("x", 2), "size_confidence": ("size_x", 3), "subtype_flags": ("subtype", 3),
               "line": ("line_start_x", 4)})
# The low three sighting bits (distant, partial, nearby) of every byte, as float32 feature columns.
_SIGHTING_BITS = np.unpackbits(np.arange(256, dtype=np.uint8)[:, None], axis=1, count=3,
                               bitorder="little").astype(np.float32)
