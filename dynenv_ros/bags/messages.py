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

from dynenv_ros.core.object_classes import ObjectClass, ObjectStatus
from dynenv_ros.perception.detections import empty
from dynenv_ros.sim.ground_truth import BodyState, WorldSnapshot

# A bag does not know which world object a detection came from: neither a real object id (>= 0) nor the
# simulator's false-positive marker (-1), so overlays draw these as ordinary detections.
TRUE_ID_UNKNOWN = -2


def stamp_ns(stamp: Any) -> int:
    """builtin_interfaces/Time → integer nanoseconds (exact, unlike float seconds)."""
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


def _object_class(value: int) -> ObjectClass | int:
    try:
        return ObjectClass(int(value))
    except ValueError:   # a class this code base does not know yet: keep the number rather than fail the replay
        return int(value)


def body_from_msg(o: Any) -> BodyState:
    """ObjectState → BodyState (field for field)."""
    return BodyState(id=int(o.id), class_id=_object_class(o.class_id), team=int(o.team), x=float(o.x),
                     y=float(o.y), yaw=float(o.yaw), vx=float(o.vx), vy=float(o.vy), yaw_rate=float(o.yaw_rate),
                     head_yaw=float(o.head_yaw), size_x=float(o.size_x), size_y=float(o.size_y),
                     status=ObjectStatus(int(o.status)), penalty_remaining=float(o.penalty_remaining),
                     goal_x=float(o.goal_x), goal_y=float(o.goal_y))


def snapshot_from_msg(msg: Any) -> WorldSnapshot:
    """WorldState (as rosbags decodes it) → WorldSnapshot, the inverse of ros.conversions.world_state."""
    return WorldSnapshot(scenario=int(msg.scenario), episode_id=int(msg.episode_id), tick=int(msg.tick),
                         tick_period=float(msg.tick_period), game_time=float(msg.game_time),
                         time_remaining=float(msg.time_remaining), phase=int(msg.phase),
                         ball_owner_team=int(msg.ball_owner_team),
                         ball_owner_remaining=float(msg.ball_owner_remaining),
                         last_touch_robot_ids=tuple(int(i) for i in msg.last_touch_robot_ids),
                         score_team_a=int(msg.score_team_a), score_team_b=int(msg.score_team_b),
                         objects=tuple(body_from_msg(o) for o in msg.objects))


def detection_rows(detections: Sequence[Any]) -> np.ndarray:
    """Detection messages → DETECTION_DTYPE rows; ``true_id`` = TRUE_ID_UNKNOWN and ``true_class`` = 0 (a bag
    carries only what the robot reported, so no false-positive or confusion marks can be drawn)."""
    rows = empty(len(detections))
    for i, d in enumerate(detections):
        rows[i] = (d.class_id, d.position.x, d.position.y, d.yaw, d.size_x, d.size_y, d.confidence, d.team,
                   d.subtype, d.fallen, d.penalized, d.line_start.x, d.line_start.y, d.line_end.x, d.line_end.y,
                   d.sighting, TRUE_ID_UNKNOWN, 0)
    return rows


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
