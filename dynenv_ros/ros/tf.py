"""The TF tree of the simulated field (docs/ros_graph.md, "TF"), so RViz and Foxglove place every robot's
detections without knowing this project.

``/tf`` (vision rate): ``map → <robot>/base_link`` (the robot's pose on the field) and
``<robot>/base_link → <robot>/camera`` (the head's yaw: the frame of the robot's DetectionArray). With the
simulator's self-localization on, REP 105's chain instead: ``map → <robot>/odom → <robot>/base_link`` composes to
the robot's pose *estimate* (``ros/pose_estimates.py``), and the truth is ``map → <robot>/ground_truth/base_link``.
``/tf_static`` (latched, once): ``map → team_a/field`` and ``map → team_b/field``, the team frames the agent's
localization and reconstruction outputs use (team B's is turned by π, so each team attacks along its +x).

Everything lies on the ground plane (z = 0): detections are 2D, so a camera frame lifted to a head height would
show every detection floating that high. Quaternions are yaw-only (REP 103: z up, yaw counter-clockwise).
"""
from __future__ import annotations

import math
from collections.abc import Sequence

from builtin_interfaces.msg import Time
from geometry_msgs.msg import TransformStamped
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from tf2_msgs.msg import TFMessage

from dynenv_ros.ros.conversions import WORLD_FRAME, camera_frame
from dynenv_ros.ros.pose_estimates import compose, ground_truth_frame, inverse, odom_frame

TF_TOPIC = "/tf"
TF_STATIC_TOPIC = "/tf_static"
TEAM_FRAMES = {"team_a/field": 0.0, "team_b/field": math.pi}


def base_frame(robot_name: str) -> str:
    return f"{robot_name}/base_link"


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
    t.transform.rotation.z = math.sin(yaw / 2.0)
    t.transform.rotation.w = math.cos(yaw / 2.0)
    return t


def robot_transforms(names: Sequence[str], poses: Sequence[tuple[float, float, float, float]],
                     stamp: Time, estimates: Sequence[Sequence[float]] | None = None,
                     odometry: Sequence[Sequence[float]] | None = None) -> TFMessage:
    """``poses[i]`` = (x, y, yaw, head_yaw) of robot ``names[i]`` in the map frame (m, rad), the truth.

    Without ``estimates``: ``map → base_link`` is the truth. With ``estimates`` and ``odometry`` ((n, 3) x, y, yaw
    each: the pose estimates in map, the odometry poses in odom): ``map → odom`` (estimate ∘ odometry⁻¹),
    ``odom → base_link`` (the odometry), so base_link sits at the estimate, and ``map → ground_truth/base_link``."""
    if len(names) != len(poses):
        raise ValueError(f"{len(names)} robot names but {len(poses)} poses")
    if (estimates is None) != (odometry is None):
        raise ValueError("estimates and odometry come together")
    transforms = []
    for i, (name, (x, y, yaw, head_yaw)) in enumerate(zip(names, poses)):
        if estimates is None:
            transforms.append(planar_transform(WORLD_FRAME, base_frame(name), x, y, yaw, stamp))
        else:
            correction = compose(estimates[i], inverse(odometry[i]))          # map → odom
            transforms.append(planar_transform(WORLD_FRAME, odom_frame(name), *correction, stamp))
            transforms.append(planar_transform(odom_frame(name), base_frame(name), *odometry[i], stamp))
            transforms.append(planar_transform(WORLD_FRAME, ground_truth_frame(name), x, y, yaw, stamp))
        transforms.append(planar_transform(base_frame(name), camera_frame(name), 0.0, 0.0, head_yaw, stamp))
    return TFMessage(transforms=transforms)


def static_transforms(stamp: Time) -> TFMessage:
    return TFMessage(transforms=[planar_transform(WORLD_FRAME, frame, 0.0, 0.0, yaw, stamp)
                                 for frame, yaw in TEAM_FRAMES.items()])
