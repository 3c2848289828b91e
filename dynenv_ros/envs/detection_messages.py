"""DetectionArray messages → the fixed-shape observation layout (``envs.padded_layout``), with no ROS import: the
messages are read by attribute, so rclpy's messages, rosbags' deserialised ones and plain objects all work. The
policy node packs what it acts on with it, the trainer node and ``dynenv-train --from-bag`` what they learn from, so
the same frames give the learner exactly the arrays the policy saw.

Both scenarios: ``spec`` is the layout's ``LayoutSpec`` (soccer's by default; driving's from
``envs.driving_observations.driving_layout_spec``). A driving car's proprioception is its ego values, read from the
SELF row its pipeline puts in every frame (docs/interfaces.md: destination as ``position``, speed and yaw rate as
``line_start``, length and width, crashed as ``fallen``, finished as ``penalized``): exactly the values the env's
``padded`` observation carries; a frame without a SELF row leaves them 0 (counted, ``self_missing``). Its ``game``
is ``game_seconds_remaining`` of the period's last frame; its previous action [throttle, brake, steering]."""
from __future__ import annotations

import math
from collections import Counter
from typing import Any

import numpy as np

from dynenv_ros.core.object_classes import ObjectClass
from dynenv_ros.envs.padded_layout import (MAX_FRAMES, MAX_SLOTS, SOCCER, LayoutSpec, PaddedLayout, clamp_features,
                                           pack_frames)
from dynenv_ros.perception.detections import FEATURE_COLUMNS, as_features, rows_from_messages

# The feature columns of a SELF row that hold the ego values (perception.driving_model.EGO_COLUMNS' order: speed,
# yaw_rate, goal_x, goal_y, length, width, crashed, finished).
EGO_FEATURES = [FEATURE_COLUMNS.index(c) for c in ("line_start_x", "line_start_y", "x", "y", "size_x", "size_y",
                                                  "fallen", "penalized")]


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
                  max_objects: int | None = None, stats: Counter | None = None, spec: LayoutSpec = SOCCER
                  ) -> tuple[dict[str, np.ndarray], int]:
    """Each robot's DetectionArray messages of one period (frame order) and previous action → the one observation
    layout (``envs.padded_layout``): the same arrays the in-process env gives for the same detections. A
    fixed-shape runtime (ONNX) sets the maxima, else the batch's own longest frame does, up to ``MAX_SLOTS`` (a
    flood of detections must not make a decision's cost explode). Returns the arrays and the number of rows
    dropped (farthest first) beyond the maxima. What a robot's vision pipeline should never send is cleaned, and
    counted in ``stats``: detections with a NaN or infinite value are left out (``detections_malformed``), NaN or
    infinite self-state and GameController values read as 0 (``values_malformed``). ``spec``: the layout's (module
    docstring)."""
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
            robot.append(clamp_features(rows, spec.feature_bound))
        frames.append(robot)
    layout = PaddedLayout.fitting(frames, max_landmarks, max_objects, spec)
    if layout.max_landmarks > MAX_SLOTS or layout.max_objects > MAX_SLOTS:
        layout = PaddedLayout(layout.frames, min(layout.max_landmarks, MAX_SLOTS), min(layout.max_objects, MAX_SLOTS),
                              spec)
    observation, dropped = pack_frames(layout, frames)
    SIDES[spec.scenario](observation, frames, periods, previous, stats)
    return observation, int(dropped.sum())


def _soccer_side(observation: dict[str, np.ndarray], frames: list[list[np.ndarray]], periods: list[list[Any]],
                 previous: list[tuple], stats: Counter | None) -> None:
    """Soccer's proprioception (each frame's head yaw, fallen, penalized, kicking), game (the GameController's
    values at the last frame) and previous action."""
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


def _driving_side(observation: dict[str, np.ndarray], frames: list[list[np.ndarray]], periods: list[list[Any]],
                  previous: list[tuple], stats: Counter | None) -> None:
    """Driving's proprioception (each frame's SELF row's ego values), game (seconds remaining at the last frame) and
    previous action (module docstring)."""
    self_class = float(ObjectClass.SELF)
    for b, (rows_of_frames, period) in enumerate(zip(frames, periods)):
        for k, rows in enumerate(rows_of_frames):
            own = rows[rows[:, 0] == self_class]
            if len(own):
                observation["proprioception"][b, k] = own[0, EGO_FEATURES]
            elif stats is not None:
                stats["self_missing"] += 1
        observation["game"][b] = (_finite(getattr(period[-1], "game_seconds_remaining", 0.0), stats),)
        observation["previous_action"][b] = previous[b]


# What each layout (``LayoutSpec.scenario``) reads from the messages besides the detection rows: a new layout adds a
# row (one lookup where there was a branch: docs/decisions.md, "A scenario registry").
SIDES = {"soccer": _soccer_side, "driving": _driving_side}
