"""A localization's pose estimates, read back into the policy's ``pose_estimate`` input (``envs/pose_features.py``),
with no ROS import: messages are read by attribute in ``geometry_msgs/PoseWithCovarianceStamped``'s layout, so
rclpy's messages, rosbags' deserialised ones and plain objects all work. ``ros/pose_estimates.py`` writes the
messages (the layout is described there) and re-exports these names; the policy nodes read with them.

- **Refused** (``pose_problem``, with the reason): a frame other than the expected one, a non-finite pose or used
  covariance entry, a quaternion that is not a unit one (|q| off by more than 1 %), or a negative variance; the
  used entries are slots 0, 1, 5, 6, 7, 11, 30, 31, 35 (x, y, yaw and their cross terms; the unused dimensions are
  ignored, whatever a stack puts there).
- **Kept** (``PoseHistory``): each robot's recent estimates; **used** (``pose_batch``): each robot's newest estimate
  at or before its period's last frame, in its team's frame, or ``LOST_ROW`` ("lost") without a recent one.
"""
from __future__ import annotations

import math
from collections import Counter, deque
from collections.abc import Sequence
from typing import Any

import numpy as np

from dynenv_ros.envs.pose_features import POSE_BOUND, POSE_COLUMNS, pose_features
from dynenv_ros.sim.frames import WORLD_FRAME

COV_X, COV_Y, COV_YAW = 0, 7, 35            # the variances' slots in the row-major 6x6 (x, y, z, roll, pitch, yaw)
USED_SLOTS = tuple(6 * r + c for r in (0, 1, 5) for c in (0, 1, 5))
# What a robot's pose input holds while it has no usable estimate ("lost"): no position, no heading, every
# standard deviation at the observation's bound.
LOST_ROW = np.array((0.0, 0.0, 0.0, 0.0, POSE_BOUND, POSE_BOUND, POSE_BOUND), np.float32)
assert len(LOST_ROW) == len(POSE_COLUMNS)
HISTORY_DEPTH = 128                          # estimates kept per robot (two periods of the largest frame count)


def stamp_ns(stamp: Any) -> int:
    """A header stamp (builtin_interfaces/Time, read by attribute) in integer nanoseconds."""
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


def pose_problem(msg: Any, frame_id: str = WORLD_FRAME) -> str:
    """Why ``msg`` cannot be a pose estimate ("" if it can)."""
    if msg.header.frame_id != frame_id:
        return f"frame_id {msg.header.frame_id!r}, expected {frame_id!r}"
    p, q = msg.pose.pose.position, msg.pose.pose.orientation
    values = (p.x, p.y, p.z, q.x, q.y, q.z, q.w)
    if not all(math.isfinite(v) for v in values):
        return "non-finite pose"
    norm = math.sqrt(q.x * q.x + q.y * q.y + q.z * q.z + q.w * q.w)
    if abs(norm - 1.0) > 0.01:
        return f"orientation is not a unit quaternion (|q| = {norm:.3g})"
    covariance = np.asarray(msg.pose.covariance, float)
    used = covariance[list(USED_SLOTS)]
    if not np.isfinite(used).all():
        return "non-finite covariance in x, y or yaw"
    variances = covariance[[COV_X, COV_Y, COV_YAW]]
    if (variances < 0).any():
        return f"negative variance (x, y, yaw: {', '.join(f'{v:.3g}' for v in variances)})"
    return ""


def message_pose(msg: Any) -> tuple[np.ndarray, np.ndarray]:
    """(x, y, yaw) and the (x, y, yaw) variances of a message that passed ``pose_problem``."""
    p, q = msg.pose.pose.position, msg.pose.pose.orientation
    yaw = math.atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z))
    covariance = msg.pose.covariance
    return (np.array((p.x, p.y, yaw)),
            np.array((covariance[COV_X], covariance[COV_Y], covariance[COV_YAW]), float))


class PoseHistory:
    """One robot's recent estimates (stamp, pose, variances), oldest first. A message stamped before the newest
    held means the clock went back (a restarted simulator, a looping bag): the history starts again from it."""

    def __init__(self, depth: int = HISTORY_DEPTH) -> None:
        self.entries: deque[tuple[int, np.ndarray, np.ndarray]] = deque(maxlen=depth)
        self.restarts = 0

    def add(self, msg: Any) -> None:
        """File a message that passed ``pose_problem``."""
        stamp = stamp_ns(msg.header.stamp)
        if self.entries and stamp < self.entries[-1][0]:
            self.entries.clear()
            self.restarts += 1
        self.entries.append((stamp, *message_pose(msg)))

    def at(self, stamp: int, max_age_ns: int) -> tuple[tuple[np.ndarray, np.ndarray] | None, str]:
        """The newest estimate stamped at or before ``stamp`` (ns) and "pose_used"; (None, "pose_missing") without
        one, (None, "pose_stale") when it is more than ``max_age_ns`` older. Older entries are forgotten."""
        chosen = None
        for k in range(len(self.entries) - 1, -1, -1):
            if self.entries[k][0] <= stamp:
                chosen = k
                break
        if chosen is None:
            return None, "pose_missing"
        for _ in range(chosen):
            self.entries.popleft()
        when, pose, variances = self.entries[0]
        if stamp - when > max_age_ns:
            return None, "pose_stale"
        return (pose, variances), "pose_used"


def pose_batch(histories: Sequence[PoseHistory], stamps: Sequence[int], teams: Sequence[int], max_age_ns: int,
               counts: Counter[str] | None = None) -> np.ndarray:
    """(B, 7) float32 ``pose_estimate`` rows: robot b's estimate at or before ``stamps[b]`` (ns: its period's last
    frame) in its team's frame (``teams[b]`` ±1), ``LOST_ROW`` where it has none recent enough. ``counts`` gets
    one of pose_used, pose_missing, pose_stale per robot."""
    rows = np.tile(LOST_ROW, (len(histories), 1))
    found = []
    for b, (history, stamp) in enumerate(zip(histories, stamps)):
        entry, status = history.at(stamp, max_age_ns)
        if counts is not None:
            counts[status] += 1
        if entry is not None:
            found.append((b, entry))
    if found:
        index = [b for b, _ in found]
        estimates = np.array([pose for _, (pose, _) in found])
        covariances = np.zeros((len(found), 3, 3))
        covariances[:, [0, 1, 2], [0, 1, 2]] = [variances for _, (_, variances) in found]
        rows[index] = pose_features(estimates, covariances, np.asarray(teams, float)[index])
    return rows


__all__ = ["COV_X", "COV_Y", "COV_YAW", "HISTORY_DEPTH", "LOST_ROW", "USED_SLOTS", "PoseHistory", "message_pose",
           "pose_batch", "pose_problem", "stamp_ns"]
