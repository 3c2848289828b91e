"""A scripted policy for one robot as a ROS 2 node (``ros2 run dynenv_ros scripted_policy --ros-args -p robot:=…``).

It acts once per motion period: when its robot's last detection frame of a period and the ground truth of the same
instant have both arrived, it decides from the ground truth (the scripted policies of ``soccer/scripted.py``) and
publishes the action for the next period, stamped with that frame's time and framed in ``<robot>/base_link``.
Waiting for both keeps stepped runs deterministic whatever the order in
which DDS delivers the two topics.
"""
from __future__ import annotations

from collections import OrderedDict
from collections.abc import Sequence
from typing import Any

import numpy as np
from dynenv_msgs.msg import Action, DetectionArray, WorldState
from rclpy.exceptions import ParameterException
from rclpy.node import Node

from dynenv_ros.ros import conversions as cv
from dynenv_ros.ros import topics
from dynenv_ros.ros.authentication import action_tagger
from dynenv_ros.ros.diagnostics import Heartbeat
from dynenv_ros.ros.node_runner import run_node
from dynenv_ros.ros.parameters import declare_int, declare_str
from dynenv_ros.ros.qos import action_stream, sim_stream
from dynenv_ros.ros.tf import base_frame
from dynenv_ros.soccer.scripted import ChaserPolicy, GoalkeeperPolicy, RandomPolicy

POLICIES = ("chaser", "keeper", "random")


class ScriptedPolicyNode(Node):
    def __init__(self, **node_options: Any) -> None:
        super().__init__("scripted_policy", **node_options)
        self.robot = declare_str(self, "robot", "team_a_0", "Robot to control (team_a_0, team_b_1, …).",
                                 read_only=True)
        kind = declare_str(self, "policy", "chaser", "Scripted behaviour.", choices=POLICIES, read_only=True)
        seed = declare_int(self, "seed", 0, 0, 2**31 - 1, "Seed of the random policy.", read_only=True)
        parts = self.robot.split("_")
        if len(parts) != 3 or parts[0] != "team" or parts[1] not in "ab" or not parts[2].isdigit():
            raise ParameterException(f"robot must look like team_a_0, got {self.robot!r}", ["robot"])
        self.tag_action = action_tagger(self, [self.robot])      # secrets_dir: its team's secret (issue 27)
        self.policy = {"chaser": lambda: ChaserPolicy(), "keeper": lambda: GoalkeeperPolicy(),
                       "random": lambda: RandomPolicy(np.random.default_rng(seed))}[kind]()
        self.robot_id: int | None = None       # learned from the first detection message (depends on team size)
        self._truth: OrderedDict[tuple[int, int], WorldState] = OrderedDict()
        self._waiting: dict[tuple[int, int], DetectionArray] = {}
        self.actions_sent = 0
        self.heartbeat = Heartbeat(self, "scripted policy", lambda: {"robot": self.robot, "policy": kind,
                                                                     "actions_sent": self.actions_sent})
        qos = sim_stream()
        self.action_pub = self.create_publisher(Action, topics.local(topics.action(self.robot)), action_stream())
        self.create_subscription(WorldState, topics.local(topics.WORLD_STATE), self._on_truth, qos)
        self.create_subscription(DetectionArray, topics.local(topics.detections(self.robot)), self._on_detections,
                                 qos)

    @staticmethod
    def _key(episode: int, stamp) -> tuple[int, int, int]:
        """Episodes restart the clock at 0, so an instant is (episode, sec, nanosec)."""
        return (episode, stamp.sec, stamp.nanosec)

    def _on_truth(self, msg: WorldState) -> None:
        key = self._key(msg.episode_id, msg.header.stamp)
        self._truth[key] = msg
        self._truth.move_to_end(key)
        while len(self._truth) > 50:
            self._truth.popitem(last=False)
        if key in self._waiting:
            self._act(self._waiting.pop(key), msg)

    def _on_detections(self, msg: DetectionArray) -> None:
        if msg.frame_index != msg.frames_per_period - 1:
            return
        key = self._key(msg.episode_id, msg.header.stamp)
        truth = self._truth.get(key)
        if truth is None:
            self._waiting[key] = msg
            while len(self._waiting) > 50:      # a ground truth that never came: forget the oldest wait
                self._waiting.pop(next(iter(self._waiting)))
        else:
            self._act(msg, truth)

    def _act(self, frame: DetectionArray, truth: WorldState) -> None:
        self.robot_id = frame.robot_id
        action = self.policy.act(cv.snapshot_from_msg(truth), frame.robot_id)
        msg = cv.action_msg(action, robot_id=frame.robot_id, episode_id=frame.episode_id,
                            motion_period=frame.motion_period + 1, stamp=frame.header.stamp)
        msg.header.frame_id = base_frame(self.robot)      # stamped with the observation it answers (sim time)
        self.tag_action(self.robot, msg, self.action_pub)
        self.action_pub.publish(msg)
        self.actions_sent += 1


def main(args: Sequence[str] | None = None) -> int:
    return run_node(ScriptedPolicyNode, args)


if __name__ == "__main__":
    raise SystemExit(main())
