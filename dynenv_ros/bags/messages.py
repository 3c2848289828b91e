"""rosbags-decoded messages → the core's records (WorldSnapshot, DETECTION_DTYPE rows) and plain Python values.

rosbags decodes into its own dataclasses (same field names as the generated classes, numpy arrays for primitive
sequences), so these helpers work on attributes only and never import rclpy or dynenv_msgs: bag tools run on
machines without ROS.
"""
from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from dynenv_ros.perception.detections import rows_from_messages
from dynenv_ros.sim.ground_truth import body_from_msg, snapshot_from_msg  # noqa: F401  (re-exported)

# A bag does not know which world object a detection came from: neither a real object id (>= 0) nor the
# simulator's false-positive marker (-1), so overlays draw these as ordinary detections.
TRUE_ID_UNKNOWN = -2


def stamp_ns(stamp: Any) -> int:
    """builtin_interfaces/Time → integer nanoseconds (exact, unlike float seconds)."""
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


def detection_rows(detections: Sequence[Any]) -> np.ndarray:
    """Detection messages → DETECTION_DTYPE rows; ``true_id`` = TRUE_ID_UNKNOWN and ``true_class`` = 0 (a bag
    carries only what the robot reported, so no false-positive or confusion marks can be drawn)."""
    return rows_from_messages(detections, TRUE_ID_UNKNOWN)


def to_plain(value: Any) -> Any:
    """A decoded message as dicts, lists and scalars (for YAML/JSON output); numpy values become Python ones."""
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {f.name: to_plain(getattr(value, f.name)) for f in dataclasses.fields(value)
                if not f.name.startswith("__")}   # rosbags' __msgtype__ is a class attribute, not data
    if isinstance(value, np.ndarray):
        return [to_plain(v) for v in value.tolist()]
    if isinstance(value, (list, tuple)):
        return [to_plain(v) for v in value]
    if isinstance(value, np.generic):
        return value.item()
    return value


def json_safe(value: Any) -> Any:
    """NaN and infinities are not JSON: they become null (NaN is how messages say "undefined", e.g. a ball's yaw)."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {k: json_safe(v) for k, v in value.items()}
    if isinstance(value, list):
        return [json_safe(v) for v in value]
    return value
