"""How the policy node takes its inputs off ROS: the QoS of its detection and pose-estimate subscriptions, taking
the messages already waiting on one (so a decision acts on the newest complete period), and the DetectionArray
messages that stand in for frames that never came (``partial_periods.fill``, a new policy's trial decision before any
frame arrived). The decider (``decider.py``) reads them by attribute, like every other frame.
"""
from __future__ import annotations

from typing import Any

from dynenv_msgs.msg import DetectionArray
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from dynenv_ros.agent.export import MAX_FRAMES
from dynenv_ros.ros.pose_estimates import HISTORY_DEPTH

# Keep-last depth of each robot's detection subscription: two periods of the largest frame count accepted. Stepped
# mode publishes at most one period per robot and then waits for the actions — except at an episode's end, when
# the last period and the next episode's first follow each other — so nothing a stepped game needs is ever
# lost; in real time the queue is bounded whatever the policy's speed (a slow one finds at most this many frames,
# takes them all and acts on the newest complete period).
DETECTION_DEPTH = 2 * MAX_FRAMES


def pose_qos() -> QoSProfile:
    """Reliable, keep-last ``HISTORY_DEPTH``: matches the simulator's writers and reliable localization stacks
    (AMCL's, robot_localization's); a best-effort publisher does not match it (docs/deploy.md)."""
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=HISTORY_DEPTH, reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.VOLATILE)


def detection_qos() -> QoSProfile:
    """Reliable (matches the simulator's writers), keep-last ``DETECTION_DEPTH``: bounded, lossless when stepped."""
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=DETECTION_DEPTH, reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.VOLATILE)


def waiting(sub: Any, limit: int):
    """The messages already waiting on ``sub``, at most ``limit``: the subscription handle's take, what rclpy's
    executor itself calls (rclpy has no public take); none on an rclpy without it (the bounded queue alone then
    limits staleness)."""
    for _ in range(limit):
        try:
            with sub.handle:
                taken = sub.handle.take_message(sub.msg_type, sub.raw)
        except AttributeError:
            return
        if taken is None:
            return
        yield taken[0]


def empty_like(like: DetectionArray, index: int, stamp_ns: int) -> DetectionArray:
    """A frame that never came: ``like``'s robot, period and own state, no detections, its slot's stamp."""
    msg = DetectionArray(robot_id=like.robot_id, episode_id=like.episode_id, motion_period=like.motion_period,
                         frame_index=index, frames_per_period=like.frames_per_period, head_yaw=like.head_yaw,
                         self_fallen=like.self_fallen, self_penalized=like.self_penalized,
                         self_kicking=like.self_kicking, ball_owner=like.ball_owner,
                         ball_owner_seconds=like.ball_owner_seconds,
                         game_seconds_remaining=like.game_seconds_remaining)
    msg.header.frame_id = like.header.frame_id
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp_ns, 1_000_000_000)
    return msg


def empty_period(frames: int) -> list[DetectionArray]:
    """A period of ``frames`` frames with no detections and no robot state (a trial before any frame came)."""
    return [DetectionArray(frame_index=k, frames_per_period=frames) for k in range(frames)]


__all__ = ["DETECTION_DEPTH", "detection_qos", "empty_like", "empty_period", "pose_qos", "waiting"]
