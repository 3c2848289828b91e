"""The attacker of test_trainer_poison.py, a process of its own on the test's ROS domain: it reads a robot's
detections and, for every period it sees, publishes forged Actions for the periods that have not run yet (current
policy version, extreme or plausible learning fields) and forged feedback (NaN, huge rewards). Runs ``seconds``."""
from __future__ import annotations

import math
import sys
import time

import rclpy
from dynenv_msgs.msg import Action, DetectionArray, StepFeedback, WeightsAnnouncement

from dynenv_ros.ros import topics
from dynenv_ros.ros.qos import action_stream, latched, sim_stream


def main(robot: str, seconds: float) -> None:
    rclpy.init()
    node = rclpy.create_node("attacker")
    actions = node.create_publisher(Action, f"/{robot}/action", action_stream())
    feedback = node.create_publisher(StepFeedback, f"/{robot}/feedback", sim_stream())
    version = [1]
    node.create_subscription(WeightsAnnouncement, topics.WEIGHTS_ANNOUNCEMENT,     # the current version, in clear
                             lambda m: version.__setitem__(0, int(m.version)), latched(1))
    sent = [0]

    def on_frame(msg: DetectionArray) -> None:
        if msg.frame_index != 0:
            return
        for ahead, (log_prob, value) in enumerate(((-1e30, 3e38), (-0.5, 1.0), (-1e30, 0.0)), start=2):
            actions.publish(Action(robot_id=msg.robot_id, episode_id=msg.episode_id,
                                   motion_period=msg.motion_period + ahead, walk=2,
                                   policy_version=version[0], log_prob=log_prob, value=value))
            sent[0] += 1
        for reward in (math.nan, 1e30):
            feedback.publish(StepFeedback(robot_id=msg.robot_id, episode_id=msg.episode_id,
                                          motion_period=msg.motion_period + 2, reward_primary=reward))
            sent[0] += 1

    node.create_subscription(DetectionArray, f"/{robot}/detections", on_frame, sim_stream())
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        rclpy.spin_once(node, timeout_sec=0.05)
    print(f"sent {sent[0]}", flush=True)
    node.destroy_node()
    rclpy.shutdown()


if __name__ == "__main__":
    main(sys.argv[1], float(sys.argv[2]))
