"""What the simulator tells a team's stack beyond its vision (issue 41): the robot's own joints and fall state, and
the GameController on UDP. Composed into the simulator node (``SimRobotIO``); soccer only.

- With ``ros_sports`` on, per robot and vision frame, before that frame's soccer_vision_3d arrays:
  ``<robot>/joint_states`` (sensor_msgs/JointState, joint ``HeadYaw``, the head yaw at the frame, stamped with it) and
  ``<robot>/fallen`` (std_msgs/Bool): what a robot's joint driver and fall detector publish, so the policy node's
  ros-sports input can turn detections into the camera frame and knows the robot is down.
- With ``gc_udp_port`` ≥ 1, the game's RoboCupGameControlData packet (struct ``gc_struct_version``: 18, or 15 for
  readers of the 2023 struct such as game_controller_spl 4.0.0) is sent to ``gc_udp_host``:``gc_udp_port`` at each
  motion period's first frame (0.5 s: the GameController's 2 Hz), and with ``gc_return_port`` ≥ 0 the robots' return
  packets are read there (every frame, without blocking; refused ones counted by reason: ``gamecontroller.udp``).
  Penalties carry the SPL code of the referee's reason (``gamecontroller.game_state``).
"""
from __future__ import annotations

from collections import Counter
from typing import Any

from rclpy.exceptions import ParameterException
from sensor_msgs.msg import JointState
from std_msgs.msg import Bool, Header

from dynenv_ros.gamecontroller import packet as gc
from dynenv_ros.gamecontroller.game_state import game_control_data, penalty_code
from dynenv_ros.gamecontroller.udp import GameControllerLink
from dynenv_ros.ros import topics
from dynenv_ros.ros.parameters import declare_int, declare_str
from dynenv_ros.sim.frames import base_frame

HEAD_YAW_JOINT = "HeadYaw"       # the NAO's name, the policy node's default head_yaw_joint


class SimRobotIO:
    """The simulator's joint states, fall flags and GameController packets (module docstring)."""

    def __init__(self, node: Any, names: list[str], ros_sports: bool, soccer: bool,
                 publish: Any, qos: Any) -> None:
        fixed = dict(read_only=True)
        port = declare_int(node, "gc_udp_port", -1, -1, 65535, "Robocup: send the GameController's UDP packet "
                           "(RGme) to this port each motion period (3838: the GameController's); -1 off.", **fixed)
        host = declare_str(node, "gc_udp_host", "127.0.0.1", "Where the GameController packets go (a broadcast "
                           "address such as 255.255.255.255 broadcasts).", **fixed)
        return_port = declare_int(node, "gc_return_port", -1, -1, 65535, "Read the robots' GameController return "
                                  "packets (RGrt) on this port (3939: the GameController's; 0 any free one); -1 "
                                  "off.", **fixed)
        version = declare_int(node, "gc_struct_version", gc.GAMECONTROLLER_STRUCT_VERSION, 15, 18, "The RGme struct "
                              "version sent: 18 (GameController3), or 15 (the 2023 struct, game_controller_spl 4.0.0's "
                              "reader).", **fixed)
        if version not in gc.SUPPORTED_STRUCT_VERSIONS:
            raise ParameterException(f"gc_struct_version must be one of {gc.SUPPORTED_STRUCT_VERSIONS}",
                                     ["gc_struct_version"])
        if not soccer and (port >= 0 or return_port >= 0):
            raise ParameterException("the GameController is robocup's", ["gc_udp_port", "gc_return_port"])
        if port == 0:
            raise ParameterException("gc_udp_port must name the port the packets go to (1 … 65535) or be -1",
                                     ["gc_udp_port"])
        self.node, self.names, self.publish, self.version = node, names, publish, version
        self.counts: Counter[str] = Counter()
        self.team_numbers = (node.get_parameter("gc_team_number_a").value,
                             node.get_parameter("gc_team_number_b").value) if soccer else (1, 2)
        if port > 0 and self.team_numbers[0] == self.team_numbers[1]:
            raise ParameterException(f"the teams need distinct numbers, got {list(self.team_numbers)}",
                                     ["gc_team_number_a", "gc_team_number_b"])
        self.joint_pubs: list[Any] = []
        self.fallen_pubs: list[Any] = []
        if ros_sports and soccer:
            self.joint_pubs = [node.create_publisher(JointState, topics.joint_states(n), qos) for n in names]
            self.fallen_pubs = [node.create_publisher(Bool, topics.fallen(n), qos) for n in names]
        self.link: GameControllerLink | None = None
        if port > 0:
            broadcast = host.endswith(".255")
            try:
                self.link = GameControllerLink(host, port, return_port, broadcast=broadcast, counts=self.counts)
            except OSError as error:
                raise ParameterException(f"GameController UDP: {error}", ["gc_udp_port", "gc_return_port"]) from None
            where = f"; return packets on port {self.link.return_port}" if self.link.return_port else ""
            node.get_logger().info(f"GameController packets (struct {version}) to {host}:{port}{where}")
        self.packet_number = 0
        self.penalties: dict[int, int] = {}

    def frame(self, output: Any, k: int, frame: Any, stamp: Any) -> None:
        """Frame ``k`` of a period: the joint states and fall flags, and at the period's first frame the packet."""
        for i, robot in enumerate(frame.robots if self.joint_pubs else ()):
            header = Header(stamp=stamp, frame_id=base_frame(self.names[i]))
            self.publish(self.joint_pubs[i], JointState(header=header, name=[HEAD_YAW_JOINT],
                                                        position=[float(robot.head_yaw)]))
            self.publish(self.fallen_pubs[i], Bool(data=bool(robot.fallen)))
        if self.link is None:
            return
        if k == 0:
            if output.motion_period == 0:
                self.penalties.clear()
            for event in output.events:
                if event.kind == "penalty" and event.robot is not None:
                    self.penalties[event.robot] = penalty_code(event.detail)
            data = game_control_data(frame.snapshot, players_per_team=len(self.names) // 2,
                                     team_numbers=self.team_numbers, packet_number=self.packet_number,
                                     penalties=self.penalties, version=self.version)
            self.link.send(data)
            self.packet_number = (self.packet_number + 1) % 256
        self.link.receive()

    def diagnostics(self) -> dict[str, str]:
        return {k: str(v) for k, v in sorted(self.counts.items())}

    def close(self) -> None:
        if self.link is not None:
            self.link.close()
            self.link = None


__all__ = ["HEAD_YAW_JOINT", "SimRobotIO"]
