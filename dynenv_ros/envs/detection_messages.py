"""DetectionArray messages → the fixed-shape observation layout (``envs.padded_layout``), with no ROS import: the
messages are read by attribute, so rclpy's messages, rosbags' deserialised ones and plain objects all work. The
policy node packs what it acts on with it, the trainer node and ``dynenv-train --from-bag`` what they learn from, so
the same frames give the learner exactly the arrays the policy saw."""
from __future__ import annotations

import math
from collections import Counter
from typing import Any

import numpy as np

from dynenv_ros.envs.padded_layout import MAX_FRAMES, MAX_SLOTS, PaddedLayout, clamp_features, pack_frames
from dynenv_ros.perception.detections import as_features, rows_from_messages


def frame_problem(msg: Any) -> str:
    """Why a DetectionArray cannot be part of a period ('' if it can)."""
    if not 1 <= msg.frames_per_period <= MAX_FRAMES:
        return f"frames_per_period {msg.frames_per_period} outside 1..{MAX_FRAMES}"
    if msg.frame_index >= msg.frames_per_period:
        return f"frame_index {msg.frame_index} not below frames_per_period {msg.frames_per_period}"
    return ""


def _finite(value: float, stats: Counter | None) -> float:
    value = float(value)
    if math.isfinite(value):
        return value
    if stats is not None:
        stats["values_malformed"] += 1
    return 0.0


def pack_messages(periods: list[list[Any]], previous: list[tuple], max_landmarks: int | None = None,
                  max_objects: int | None = None, stats: Counter | None = None
                  ) -> tuple[dict[str, np.ndarray], int]:
    """Each robot's DetectionArray messages of one period (frame order) and previous action → the one observation
    layout (``envs.padded_layout``): the same arrays the in-process env gives for the same detections. A
    fixed-shape runtime (ONNX) sets the maxima, else the batch's own longest frame does, up to ``MAX_SLOTS`` (a
    flood of detections must not make a decision's cost explode). Returns the arrays and the number of rows
    dropped (farthest first) beyond the maxima. What a robot's vision pipeline should never send is cleaned, and
    counted in ``stats``: detections with a NaN or infinite value are left out (``detections_malformed``), NaN or
    infinite self-state and GameController values read as 0 (``values_malformed``)."""
    frames = []
    for period in periods:
        robot = []
        for msg in period:
            rows = as_features(rows_from_messages(msg.detections))
            finite = np.isfinite(rows).all(axis=1)        # before clamping: an infinite size is no far detection
            if not finite.all():
                rows = rows[finite]
                if stats is not None:
                    stats["detections_malformed"] += int((~finite).sum())
            robot.append(clamp_features(rows))
        frames.append(robot)
    layout = PaddedLayout.fitting(frames, max_landmarks, max_objects)
    if layout.max_landmarks > MAX_SLOTS or layout.max_objects > MAX_SLOTS:
        layout = PaddedLayout(layout.frames, min(layout.max_landmarks, MAX_SLOTS), min(layout.max_objects, MAX_SLOTS))
    observation, dropped = pack_frames(layout, frames)
    for b, period in enumerate(periods):
        for k, msg in enumerate(period):
            observation["proprioception"][b, k] = (_finite(msg.head_yaw, stats), msg.self_fallen,
                                                   msg.self_penalized, getattr(msg, "self_kicking", False))
        last = period[-1]
        # Fields a bag recorded before they existed (rosbags reads its own definition) read as 0.
        observation["game"][b] = (getattr(last, "ball_owner", 0),
                                  _finite(getattr(last, "ball_owner_seconds", 0.0), stats),
                                  _finite(getattr(last, "game_seconds_remaining", 0.0), stats))
        observation["previous_action"][b] = previous[b]
    return observation, int(dropped.sum())
