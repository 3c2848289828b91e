"""The reference frames of the simulated world as plain numbers: frame names, planar poses and the transform tree.

ROS-free, so the TF publisher (``ros/tf.py``) and the Foxglove live view (``live_view/``) stream one tree, built
once here. Frames follow REP 103 (x forward, y left, z up, yaw counter-clockwise, metres and radians) and REP 105
(``map → <robot>/odom → <robot>/base_link``); docs/ros_graph.md, "TF", says what each frame means.

Everything lies on the ground plane (z = 0): detections are 2D, so a camera frame lifted to a head height would
show every detection floating that high. A transform is therefore (parent, child, x, y, yaw).
"""
from __future__ import annotations

import math
from collections.abc import Sequence
from typing import NamedTuple

WORLD_FRAME = "map"
TEAM_FRAMES = {"team_a/field": 0.0, "team_b/field": math.pi}   # team B's is turned by π: each attacks along +x


class PlanarTransform(NamedTuple):
    """The pose of ``child`` in ``parent`` on the ground plane: translation (x, y, 0) m, rotation ``yaw`` rad."""
    parent: str
    child: str
    x: float
    y: float
    yaw: float


def base_frame(robot_name: str) -> str:
    return f"{robot_name}/base_link"


def camera_frame(robot_name: str) -> str:
    return f"{robot_name}/camera"


def odom_frame(robot: str) -> str:
    return f"{robot}/odom"


def ground_truth_frame(robot: str) -> str:
    """The robot's true pose (map → this), beside the estimate's chain: no name shared with it."""
    return f"{robot}/ground_truth/base_link"


def yaw_quaternion(yaw: float, pitch: float = 0.0) -> tuple[float, float, float, float]:
    """(x, y, z, w) of the rotation yaw about z, then pitch about the new y axis (ZYX order, no roll)."""
    cy, sy = math.cos(yaw / 2), math.sin(yaw / 2)
    cp, sp = math.cos(pitch / 2), math.sin(pitch / 2)
    return (-sy * sp, cy * sp, sy * cp, cy * cp)


def wrapped(a: float) -> float:
    """An angle in [−π, π)."""
    return (a + math.pi) % (2 * math.pi) - math.pi


def compose(a: Sequence[float], b: Sequence[float]) -> tuple[float, float, float]:
    """Planar poses x, y, yaw: ``a ∘ b`` (b expressed in a's frame, brought to a's parent). Plain floats: the
    simulator composes a few per robot and frame, where numpy's per-call cost dominated."""
    c, s = math.cos(a[2]), math.sin(a[2])
    return (a[0] + c * b[0] - s * b[1], a[1] + s * b[0] + c * b[1], wrapped(a[2] + b[2]))


def inverse(a: Sequence[float]) -> tuple[float, float, float]:
    """The inverse of a planar pose: ``compose(a, inverse(a))`` is the identity."""
    c, s = math.cos(a[2]), math.sin(a[2])
    return (-c * a[0] - s * a[1], s * a[0] - c * a[1], -a[2])


def robot_frames(names: Sequence[str], poses: Sequence[tuple[float, float, float, float]],
                 estimates: Sequence[Sequence[float]] | None = None,
                 odometry: Sequence[Sequence[float]] | None = None) -> list[PlanarTransform]:
    """The robots' part of the tree. ``poses[i]`` = (x, y, yaw, head_yaw) of robot ``names[i]`` in the map frame
    (m, rad), the truth.

    Without ``estimates``: ``map → base_link`` is the truth. With ``estimates`` and ``odometry`` ((n, 3) x, y, yaw
    each: the pose estimates in map, the odometry poses in odom): ``map → odom`` (estimate ∘ odometry⁻¹),
    ``odom → base_link`` (the odometry), so base_link sits at the estimate, and ``map → ground_truth/base_link``.
    Either way ``base_link → camera`` turns by the head's yaw."""
    if len(names) != len(poses):
        raise ValueError(f"{len(names)} robot names but {len(poses)} poses")
    if (estimates is None) != (odometry is None):
        raise ValueError("estimates and odometry come together")
    transforms = []
    for i, (name, (x, y, yaw, head_yaw)) in enumerate(zip(names, poses)):
        if estimates is None or odometry is None:
            transforms.append(PlanarTransform(WORLD_FRAME, base_frame(name), x, y, yaw))
        else:
            correction = compose(estimates[i], inverse(odometry[i]))          # map → odom
            transforms.append(PlanarTransform(WORLD_FRAME, odom_frame(name), *correction))
            transforms.append(PlanarTransform(odom_frame(name), base_frame(name), *odometry[i]))
            transforms.append(PlanarTransform(WORLD_FRAME, ground_truth_frame(name), x, y, yaw))
        transforms.append(PlanarTransform(base_frame(name), camera_frame(name), 0.0, 0.0, head_yaw))
    return transforms


def static_frames() -> list[PlanarTransform]:
    """``map → team_a/field`` and ``map → team_b/field``: the team frames of the agent's localization outputs."""
    return [PlanarTransform(WORLD_FRAME, frame, 0.0, 0.0, yaw) for frame, yaw in TEAM_FRAMES.items()]
