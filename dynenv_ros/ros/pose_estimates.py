"""Self-localization on ROS (docs/ros_graph.md, "Self-localization"): the simulator's emulated pose estimates as
``geometry_msgs/PoseWithCovarianceStamped`` and the REP 105 frames, and the way back, from any localization's
messages to the policy's ``pose_estimate`` input (``envs/pose_features.py``).

The message layout is defined here, once; the way back reads it (ROS-free, ``envs/pose_messages.py``):

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
- **The way back** (``pose_problem``, ``PoseHistory``, ``pose_batch``, re-exported here): in
  ``envs/pose_messages.py``, which reads the messages by attribute, so the policy node's ROS-free decider uses it.
"""
from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from builtin_interfaces.msg import Time
from geometry_msgs.msg import PoseWithCovarianceStamped

from dynenv_ros.envs.pose_messages import (COV_X, COV_Y, COV_YAW, HISTORY_DEPTH, LOST_ROW, USED_SLOTS,  # noqa: F401
                                           PoseHistory, message_pose, pose_batch, pose_problem, stamp_ns)
from dynenv_ros.ros.conversions import WORLD_FRAME
from dynenv_ros.ros.parameters import declare_float, declare_str
from dynenv_ros.sim.frames import (compose, ground_truth_frame, inverse, odom_frame,  # noqa: F401
                                   yaw_quaternion)

UNUSED_SLOTS = (14, 21, 28)                  # z, roll, pitch
UNUSED_VARIANCE = 1e6                        # "not estimated" (m², rad²)
# EmulatedOdometry: faster than this within one frame is a robot carried, not walked (a NAO walks ≈ 0.1–0.3 m/s).
CARRIED_SPEED = 2.0                          # m/s
CARRIED_MIN_STEP = 0.2                       # m: the threshold never drops below this (fast vision rates)
CARRIED_TURN = math.pi / 2                   # rad within one frame


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


def declare_pose_input(node, when: str) -> tuple[float, str]:
    """The read-only parameters of a node that reads ``<robot>/pose_estimate``: ``pose_max_age`` (s) and
    ``pose_frame``; ``when`` starts the age's description (which estimates it applies to)."""
    max_age = declare_float(node, "pose_max_age", 0.5, 0.0, 60.0, f"{when}: the newest <robot>/pose_estimate at or "
                            "before a period's last frame older than this (s, stamps) is 'lost'.", read_only=True)
    frame = declare_str(node, "pose_frame", WORLD_FRAME, "The frame_id a pose estimate must have (others are "
                        "refused).", read_only=True)
    return max_age, frame


__all__ = ["COV_X", "COV_Y", "COV_YAW", "HISTORY_DEPTH", "UNUSED_SLOTS", "UNUSED_VARIANCE", "LOST_ROW", "EmulatedOdometry",
           "PoseHistory", "compose", "declare_pose_input", "ground_truth_frame", "inverse", "message_pose", "odom_frame", "pose_batch",
           "pose_message", "pose_problem", "stamp_ns"]
