"""Standard vision messages in and out (``ros2 run dynenv_ros vision_adapter``; docs/ros_graph.md, "Standard vision
messages").

Forward (default): each robot's ``/<robot>/detections`` (dynenv_msgs/DetectionArray) is republished as
``/<robot>/detections_3d`` (vision_msgs/Detection3DArray) with the error model's covariances, for RViz's
vision_msgs displays, trackers and other generic tools.

Reverse (``reverse:=true``): a robot's own vision stack publishes ``/<robot>/detections_3d``; the adapter turns each
message into the DetectionArray the policy node reads, numbering frames and motion periods from the stamps at the
configured rates (frame = round(stamp·vision_hz); period = frame // frames_per_period). Labels outside the documented
vocabulary are dropped and counted. The robot's own state (head yaw, fallen, GameController data) is not in
vision_msgs and is left at its defaults.
"""
from __future__ import annotations

from collections import Counter
from collections.abc import Sequence
from typing import Any

from dynenv_msgs.msg import DetectionArray
from rclpy.exceptions import ParameterException
from rclpy.node import Node
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from vision_msgs.msg import Detection3DArray

from dynenv_ros.perception.params import PRESETS, load_preset
from dynenv_ros.ros import topics
from dynenv_ros.ros.node_runner import run_node
from dynenv_ros.ros.parameters import declare_bool, declare_float, declare_int, declare_str, declare_str_list
from dynenv_ros.ros.vision_msgs_conversion import from_vision_msgs, to_vision_msgs
from dynenv_ros.soccer.config import robot_names

QUEUE_DEPTH = 50      # per robot topic: ten periods of 5 frames; a stalled reader never grows memory beyond it


def detections_3d(robot: str) -> str:
    return f"{robot}/detections_3d"          # relative: in the node's namespace, like every graph topic


class VisionAdapter(Node):
    def __init__(self, **node_options: Any) -> None:
        super().__init__("vision_adapter", **node_options)
        fixed = dict(read_only=True)
        players = declare_int(self, "players_per_team", 2, 1, 5, "Robots per team (names team_a_0 ...).", **fixed)
        robots = declare_str_list(self, "robots", [], "Robots to adapt; empty: all of players_per_team.", **fixed)
        self.reverse = declare_bool(self, "reverse", False, "Detection3DArray -> DetectionArray (a robot's own "
                                    "vision stack feeding the policy node) instead of the other way.", **fixed)
        preset = declare_str(self, "perception_preset", "realistic", "Error model whose covariances are attached "
                             "(use the simulator's), and whose ranges define the sighting bits in reverse.",
                             choices=PRESETS, **fixed)
        self.vision_hz = declare_float(self, "vision_hz", 10.0, 0.1, 1000.0, "Reverse: camera frame rate.", **fixed)
        self.frames_per_period = declare_int(self, "frames_per_period", 5, 1, 255, "Reverse: vision frames per "
                                             "motion period.", **fixed)
        self.episode_id = declare_int(self, "episode_id", 1, 0, 2**32 - 1, "Reverse: episode id to stamp.", **fixed)
        names = robot_names(players)
        unknown = [r for r in robots if r not in names]
        if unknown:
            raise ParameterException(f"unknown robots {unknown}; robots are {names}", ["robots"])
        self.names = list(robots) or names
        self.params = load_preset(preset)
        self.converted = 0
        self.dropped: Counter[str] = Counter()
        qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=QUEUE_DEPTH, reliability=ReliabilityPolicy.RELIABLE)
        self.publishers_by_robot = {}
        for i, name in enumerate(self.names):
            robot_id = names.index(name)
            if self.reverse:
                publisher = self.create_publisher(DetectionArray, topics.local(topics.detections(name)), qos)
                self.create_subscription(Detection3DArray, detections_3d(name),
                                         self._reverse_callback(robot_id, publisher), qos)
            else:
                publisher = self.create_publisher(Detection3DArray, detections_3d(name), qos)
                self.create_subscription(DetectionArray, topics.local(topics.detections(name)),
                                         self._forward_callback(publisher),
                                         qos)
            self.publishers_by_robot[name] = publisher
        self.get_logger().info(f"{'reverse' if self.reverse else 'forward'} for {', '.join(self.names)}")

    def _forward_callback(self, publisher):
        def convert(msg: DetectionArray) -> None:
            publisher.publish(to_vision_msgs(msg, self.params))
            self.converted += 1
        return convert

    def _reverse_callback(self, robot_id: int, publisher):
        def convert(msg: Detection3DArray) -> None:
            seconds = msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9
            frame = round(seconds * self.vision_hz)
            out, dropped = from_vision_msgs(msg, self.params, robot_id=robot_id, episode_id=self.episode_id,
                                            motion_period=frame // self.frames_per_period,
                                            frame_index=frame % self.frames_per_period,
                                            frames_per_period=self.frames_per_period)
            if dropped:
                self.dropped.update(dropped)
                self.get_logger().warning(f"dropped detections not in the vocabulary so far: {dict(self.dropped)}",
                                          throttle_duration_sec=5.0)
            publisher.publish(out)
            self.converted += 1
        return convert


def main(args: Sequence[str] | None = None) -> int:
    return run_node(VisionAdapter, args)


if __name__ == "__main__":
    raise SystemExit(main())
