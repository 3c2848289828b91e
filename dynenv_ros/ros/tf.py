"""The TF tree of the simulated field (docs/ros_graph.md, "TF"), so RViz and Foxglove place every robot's
detections without knowing this project.

``/tf`` (vision rate): ``map → <robot>/base_link`` (the robot's pose on the field) and
``<robot>/base_link → <robot>/camera`` (the head's yaw: the frame of the robot's DetectionArray). With the
simulator's self-localization on, REP 105's chain instead: ``map → <robot>/odom → <robot>/base_link`` composes to
the robot's pose *estimate* (``ros/pose_estimates.py``), and the truth is ``map → <robot>/ground_truth/base_link``.
``/tf_static`` (latched, once): ``map → team_a/field`` and ``map → team_b/field``, the team frames the agent's
localization and reconstruction outputs use (team B's is turned by π, so each team attacks along its +x).

Everything lies on the ground plane (z = 0): detections are 2D, so a camera frame lifted to a head height would
show every detection floating that high. Quaternions are yaw-only (REP 103: z up, yaw counter-clockwise). The tree
itself is built ROS-free in ``sim/frames.py`` (the Foxglove live view streams the same one); this module stamps it.
"""
from __future__ import annotations

from collections.abc import Sequence

from builtin_interfaces.msg import Time
from geometry_msgs.msg import TransformStamped
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from tf2_msgs.msg import TFMessage

from dynenv_ros.sim.frames import (TEAM_FRAMES, PlanarTransform, base_frame, robot_frames,  # noqa: F401
                                   static_frames, yaw_quaternion)

TF_TOPIC = "/tf"
TF_STATIC_TOPIC = "/tf_static"


def tf_qos() -> QoSProfile:
    """What tf2's TransformListener subscribes with: reliable, volatile, keep-last 100."""
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=100, reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.VOLATILE)


def tf_static_qos() -> QoSProfile:
    """What tf2's StaticTransformBroadcaster offers: reliable, transient-local, keep-last 1 (late joiners get it)."""
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1, reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.TRANSIENT_LOCAL)


def planar_transform(parent: str, child: str, x: float, y: float, yaw: float, stamp: Time) -> TransformStamped:
    """A transform on the ground plane: translation (x, y, 0), rotation yaw about z."""
    t = TransformStamped()
    t.header.stamp = stamp
    t.header.frame_id = parent
    t.child_frame_id = child
    t.transform.translation.x = float(x)
    t.transform.translation.y = float(y)
    _, _, t.transform.rotation.z, t.transform.rotation.w = yaw_quaternion(float(yaw))
    return t


def tf_message(transforms: Sequence[PlanarTransform], stamp: Time) -> TFMessage:
    """The planar transforms of ``sim.frames`` (the tree the live view streams too), stamped."""
    return TFMessage(transforms=[planar_transform(*t, stamp) for t in transforms])


def robot_transforms(names: Sequence[str], poses: Sequence[tuple[float, float, float, float]],
                     stamp: Time, estimates: Sequence[Sequence[float]] | None = None,
                     odometry: Sequence[Sequence[float]] | None = None) -> TFMessage:
    """``poses[i]`` = (x, y, yaw, head_yaw) of robot ``names[i]`` in the map frame (m, rad), the truth.

    Without ``estimates``: ``map → base_link`` is the truth. With ``estimates`` and ``odometry`` ((n, 3) x, y, yaw
    each: the pose estimates in map, the odometry poses in odom): ``map → odom`` (estimate ∘ odometry⁻¹),
    ``odom → base_link`` (the odometry), so base_link sits at the estimate, and ``map → ground_truth/base_link``
    (``sim.frames.robot_frames``)."""
    return tf_message(robot_frames(names, poses, estimates, odometry), stamp)


def static_transforms(stamp: Time) -> TFMessage:
    return tf_message(static_frames(), stamp)
