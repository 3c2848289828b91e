"""The simulator's ros-sports output (issue 41, docs/interfaces.md): each robot's frames as soccer_vision_3d_msgs
in its base_link frame, and the game as game_controller_spl's RCGCD15 on its gc/data once per motion period, as
game_controller_spl relays the GameController's 2 Hz packets (one motion period is 0.5 s by default).
"""
from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

from game_controller_spl_interfaces.msg import RCGCD15
from rclpy.node import Node
from rclpy.qos import QoSProfile
from soccer_vision_3d_msgs.msg import BallArray, GoalpostArray, MarkingArray, RobotArray
from std_msgs.msg import Header

from dynenv_ros.envs.session import FrameOutput, PeriodOutput
from dynenv_ros.gamecontroller.game_state import game_control_data, penalty_code
from dynenv_ros.perception.soccer_vision_3d import soccer_vision_3d
from dynenv_ros.ros import topics
from dynenv_ros.ros.ros_sports_conversion import rcgcd15, soccer_vision_messages
from dynenv_ros.ros.topics import local
from dynenv_ros.sim.frames import base_frame


class RosSportsOutlet:
    """The ros-sports publishers of every robot, and what the GameController's packets need to remember: the packet
    number and each robot's latest penalty."""

    def __init__(self, node: Node, names: Sequence[str], qos: QoSProfile, players_per_team: int,
                 team_numbers: tuple[int, int], publish: Callable[[Any, Any], None]) -> None:
        self.names, self.players_per_team, self.team_numbers = list(names), players_per_team, team_numbers
        self._publish = publish
        self.packet_number = 0
        self.penalty_codes: dict[int, int] = {}      # robot id -> SPL penalty of its latest penalty
        self.vision_pubs = [tuple(node.create_publisher(t, local(name), qos) for t, name in (
            (BallArray, topics.soccer_vision_3d(n, "balls")), (RobotArray, topics.soccer_vision_3d(n, "robots")),
            (GoalpostArray, topics.soccer_vision_3d(n, "goalposts")),
            (MarkingArray, topics.soccer_vision_3d(n, "markings")))) for n in names]
        self.gc_pubs = [node.create_publisher(RCGCD15, local(topics.gc_data(n)), qos) for n in names]

    def episode_started(self) -> None:
        self.penalty_codes.clear()

    def period_ran(self, output: PeriodOutput) -> None:
        for event in output.events:
            if event.kind == "penalty" and event.robot is not None:
                self.penalty_codes[event.robot] = penalty_code(event.detail)

    def frame(self, k: int, frame: FrameOutput, stamp: Any) -> None:
        """Frame k of a period per robot; at a period's first frame, the game on each robot's gc/data."""
        for i, robot in enumerate(frame.robots):
            header = Header(stamp=stamp, frame_id=base_frame(self.names[i]))
            records = soccer_vision_3d(robot.detections, robot.head_yaw)
            for publisher, message in zip(self.vision_pubs[i], soccer_vision_messages(records, header)):
                self._publish(publisher, message)
        if k != 0:
            return
        data = game_control_data(frame.snapshot, players_per_team=self.players_per_team,
                                 team_numbers=self.team_numbers, packet_number=self.packet_number,
                                 penalties=self.penalty_codes)
        self.packet_number = (self.packet_number + 1) % 256
        message = rcgcd15(data)
        for publisher in self.gc_pubs:
            self._publish(publisher, message)


__all__ = ["RosSportsOutlet"]
