"""Self-localization on ROS (docs/ros_graph.md, "Self-localization"): the simulator's emulated pose estimates as
``geometry_msgs/PoseWithCovarianceStamped`` and the REP 105 frames, and the way back, from any localization's
messages to the policy's ``pose_estimate`` input (``envs/pose_features.py``).

Both directions live here, so the message layout is defined once:

- **Message** (``pose_message``): header frame ``map`` (the field frame, REP 103: x toward team B's goal, z up),
  stamp = the vision frame's sim time; position (x, y, 0), a yaw-only quaternion; the 6x6 covariance row-major over
  (x, y, z, roll, pitch, yaw): the x, y and yaw variances in slots 0, 7 and 35, ``UNUSED_VARIANCE`` (1e6) in the
  z, roll and pitch slots 14, 21, 28 (the dimensions a planar localization does not estimate: "unknown", as 2D
  odometry and localization stacks publish them), 0 elsewhere (the emulated covariance is diagonal).
- **Odometry** (``EmulatedOdometry``): ``<robot>/odom → <robot>/base_link`` is the robot's true motion, integrated
  frame to frame in its body frame since the episode started (drift-free: the emulated localization already puts
  odometry's drift into the estimate's error). A jump no walk can make within one frame (a robot carried: penalty,
  kickoff placement) is not odometry and is skipped, so the odom frame stays continuous as REP 105 requires. Each
  episode starts a new odometry (a rebooted robot): odom is where the robot stood at the kickoff.
- **map → odom** = estimate ∘ odometry⁻¹, so map → odom → base_link is the estimate (REP 105: map → odom carries
  the localization's corrections and may jump).
- **The way back** (``pose_problem``, ``PoseHistory``, ``pose_batch``): a message is refused (with the reason) for a
  frame other than the expected one, a non-finite pose or used covariance entry, a quaternion that is not a unit one
  (|q| off by more than 1 %), or a negative variance; the used entries are slots 0, 1, 5, 6, 7, 11, 30, 31, 35 (x, y,
  yaw and their cross terms; the unused dimensions are ignored, whatever a stack puts there).
"""
from __future__ import annotations

import math
from collections import Counter, deque
from collections.abc import Sequence

import numpy as np
from builtin_interfaces.msg import Time
from geometry_msgs.msg import PoseWithCovarianceStamped

from dynenv_ros.envs.pose_features import POSE_BOUND, POSE_COLUMNS, pose_features
from dynenv_ros.ros.conversions import WORLD_FRAME
from dynenv_ros.ros.parameters import declare_float, declare_str
from dynenv_ros.sim.frames import (compose, ground_truth_frame, inverse, odom_frame,  # noqa: F401
                                   yaw_quaternion)

COV_X, COV_Y, COV_YAW = 0, 7, 35            # the variances' slots in the row-major 6x6 (x, y, z, roll, pitch, yaw)
UNUSED_SLOTS = (14, 21, 28)                  # z, roll, pitch
UNUSED_VARIANCE = 1e6                        # "not estimated" (m², rad²)
USED_SLOTS = tuple(6 * r + c for r in (0, 1, 5) for c in (0, 1, 5))
# What a robot's pose input holds while it has no usable estimate ("lost"): no position, no heading, every
# standard deviation at the observation's bound.
LOST_ROW = np.array((0.0, 0.0, 0.0, 0.0, POSE_BOUND, POSE_BOUND, POSE_BOUND), np.float32)
assert len(LOST_ROW) == len(POSE_COLUMNS)
# EmulatedOdometry: faster than this within one frame is a robot carried, not walked (a NAO walks ≈ 0.1–0.3 m/s).
CARRIED_SPEED = 2.0                          # m/s
CARRIED_MIN_STEP = 0.2                       # m: the threshold never drops below this (fast vision rates)
CARRIED_TURN = math.pi / 2                   # rad within one frame
HISTORY_DEPTH = 128                          # estimates kept per robot (two periods of the largest frame count)


class EmulatedOdometry:
    """Every robot's odometry pose (odom → base_link) from its true poses, one vision frame at a time."""

    def __init__(self, frame_seconds: float) -> None:
        self.max_step = max(CARRIED_MIN_STEP, CARRIED_SPEED * frame_seconds)
        self.pose: list[tuple[float, float, float]] | None = None
        self._previous: list[tuple[float, float, float]] | None = None
        self.carried = 0                      # frames skipped as carried, all robots (a count for tests and logs)

    def restart(self) -> None:
        """A new episode: odom is set at the next frame's true poses."""
        self._previous = self.pose = None

    def reset(self, truth: Sequence[Sequence[float]]) -> None:
        """An episode starts: odom is the robots' pose now (``truth``: per robot x, y, yaw in map)."""
        self._previous = [tuple(float(v) for v in t[:3]) for t in truth]
        self.pose = [(0.0, 0.0, 0.0)] * len(self._previous)

    def step(self, truth: Sequence[Sequence[float]]) -> list[tuple[float, float, float]]:
        """Advance to ``truth`` (per robot x, y, yaw); returns the odometry poses (per robot x, y, yaw)."""
        if self._previous is None or self.pose is None:
            self.reset(truth)
            return self.pose
        poses = []
        for odom, before, now in zip(self.pose, self._previous, truth):
            delta = compose(inverse(before), now)              # the body-frame motion since the last frame
            if math.hypot(delta[0], delta[1]) > self.max_step or abs(delta[2]) > CARRIED_TURN:
                self.carried += 1
            else:
                odom = compose(odom, delta)
            poses.append(odom)
        self.pose = poses
        self._previous = [tuple(float(v) for v in t[:3]) for t in truth]
        return poses


def stamp_ns(stamp: Time) -> int:
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


_COVARIANCE_TEMPLATE = np.zeros(36)
_COVARIANCE_TEMPLATE[list(UNUSED_SLOTS)] = UNUSED_VARIANCE


def pose_message(estimate: Sequence[float], variances: Sequence[float], stamp: Time,
                 frame_id: str = WORLD_FRAME) -> PoseWithCovarianceStamped:
    """One robot's estimate (x, y, yaw) with its (x, y, yaw) variances as the module docstring lays it out."""
    msg = PoseWithCovarianceStamped()
    msg.header.stamp = stamp
    msg.header.frame_id = frame_id
    x, y, yaw = (float(v) for v in estimate)
    msg.pose.pose.position.x, msg.pose.pose.position.y = x, y
    _, _, msg.pose.pose.orientation.z, msg.pose.pose.orientation.w = yaw_quaternion(yaw)
    covariance = _COVARIANCE_TEMPLATE.copy()
    covariance[[COV_X, COV_Y, COV_YAW]] = variances
    msg.pose.covariance = covariance
    return msg


def pose_problem(msg: PoseWithCovarianceStamped, frame_id: str = WORLD_FRAME) -> str:
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


def message_pose(msg: PoseWithCovarianceStamped) -> tuple[np.ndarray, np.ndarray]:
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

    def add(self, msg: PoseWithCovarianceStamped) -> None:
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


def declare_pose_input(node, when: str) -> tuple[float, str]:
    """The read-only parameters of a node that reads ``<robot>/pose_estimate``: ``pose_max_age`` (s) and
    ``pose_frame``; ``when`` starts the age's description (which estimates it applies to)."""
    max_age = declare_float(node, "pose_max_age", 0.5, 0.0, 60.0, f"{when}: the newest <robot>/pose_estimate at or "
                            "before a period's last frame older than this (s, stamps) is 'lost'.", read_only=True)
    frame = declare_str(node, "pose_frame", WORLD_FRAME, "The frame_id a pose estimate must have (others are "
                        "refused).", read_only=True)
    return max_age, frame


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


__all__ = ["COV_X", "COV_Y", "COV_YAW", "UNUSED_SLOTS", "UNUSED_VARIANCE", "LOST_ROW", "EmulatedOdometry",
           "PoseHistory", "compose", "declare_pose_input", "ground_truth_frame", "inverse", "message_pose", "odom_frame", "pose_batch",
           "pose_message", "pose_problem", "stamp_ns"]
