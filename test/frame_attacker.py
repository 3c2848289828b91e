"""The attacker of test_frame_auth_graph.py, a process of its own on the test's ROS domain, without frames.secret.
For every genuine frame of ``robot`` it sees, it publishes forged frames on ``/<robot>/detections`` for the next
motion period (all its frame indices, so they arrive before the simulator's): one ball 0.3 m ahead at height
``MARK`` (the simulator's detections are planar, z = 0, so no genuine frame holds it; a mark in ``confidence`` would
not do: a calibrated confidence can come within any tolerance of it), untagged, with a random tag, and with a tag under ``team_b.secret`` (a robot
of the other team: a secret it may hold) on ``/<robot>/detections_mac``; and it replays the genuine frame it just saw
with its genuine tag. Runs ``seconds``, then prints what it sent."""
from __future__ import annotations

import os
import sys
from collections import Counter
from pathlib import Path

import rclpy
from ros_harness import spin_then_report
from dynenv_msgs.msg import Detection, DetectionArray
from std_msgs.msg import UInt8MultiArray

from dynenv_ros.ros.qos import sim_stream
from dynenv_ros.security.action_auth import load_secret
from dynenv_ros.security.frame_auth import detection_array_bytes, tag_frame

MARK = 0.987654


def forged_frame(genuine: DetectionArray, period: int, index: int) -> DetectionArray:
    msg = DetectionArray(robot_id=genuine.robot_id, episode_id=genuine.episode_id, motion_period=period,
                         frame_index=index, frames_per_period=genuine.frames_per_period,
                         game_seconds_remaining=genuine.game_seconds_remaining)
    msg.header.frame_id = genuine.header.frame_id
    msg.header.stamp.sec = genuine.header.stamp.sec + 1
    ball = Detection(class_id=Detection.CLASS_BALL, yaw=float("nan"), size_x=0.1, size_y=0.1, confidence=0.9)
    ball.position.x, ball.position.z = 0.3, MARK
    msg.detections = [ball]
    return msg


def main(robot: str, seconds: float, secrets_dir: str) -> None:
    rclpy.init()
    node = rclpy.create_node("frame_attacker")
    topic = f"/{robot}/detections"
    frames = node.create_publisher(DetectionArray, topic, sim_stream())
    tags = node.create_publisher(UInt8MultiArray, topic + "_mac", sim_stream())
    other = load_secret(Path(secrets_dir) / "team_b.secret")
    sent: Counter[str] = Counter()
    genuine_tags: list[bytes] = []
    attacked: set[tuple[int, int]] = set()

    def on_tag(msg: UInt8MultiArray) -> None:
        genuine_tags.append(bytes(msg.data))
        del genuine_tags[:-8]

    def on_frame(msg: DetectionArray) -> None:
        key = (msg.episode_id, msg.motion_period)
        if any(d.position.z == MARK for d in msg.detections) or msg.frame_index != 0 or key in attacked:
            return
        attacked.add(key)                                           # once a period (its own replay comes back)
        for index in range(msg.frames_per_period):
            for kind in ("untagged", "random_tag", "other_secret"):
                forged = forged_frame(msg, msg.motion_period + 1, index)
                forged.header.stamp.nanosec = len(sent) % 1000      # each forged frame's bytes differ
                sent[kind] += 1
                frames.publish(forged)
                if kind == "random_tag":
                    tags.publish(UInt8MultiArray(data=os.urandom(16)))
                elif kind == "other_secret":
                    tags.publish(UInt8MultiArray(data=tag_frame(other, detection_array_bytes(forged, topic))))
        frames.publish(msg)                                         # the genuine frame replayed, and its tag
        sent["replay"] += 1
        if genuine_tags:
            tags.publish(UInt8MultiArray(data=genuine_tags[-1]))

    node.create_subscription(DetectionArray, topic, on_frame, sim_stream())
    node.create_subscription(UInt8MultiArray, topic + "_mac", on_tag, sim_stream())
    spin_then_report(node, seconds, sent)


if __name__ == "__main__":
    main(sys.argv[1], float(sys.argv[2]), sys.argv[3])
