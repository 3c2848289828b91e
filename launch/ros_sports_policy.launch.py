"""The policy node beside a team's ROS 2 stack, for a full ROS 2 install (issue 41; docs/deploy.md, "The ros-sports
route"): one robot, the node reading the stack's soccer_vision_3d_msgs, gc/data, joint_states, fallen and
pose_estimate and commanding its cmd_vel, motion/kick and motion/head, all in the launch's namespace (the robot's).

    ros2 launch dynenv_ros ros_sports_policy.launch.py checkpoint:=agent.onnx team:=a gc_team_number:=12 player_number:=3
    ros2 launch dynenv_ros ros_sports_policy.launch.py params_file:=config/deploy_policy_node.yaml checkpoint:=agent.onnx

Arguments: ``checkpoint`` (a .onnx or .safetensors policy; default the package's shipped one), ``team`` (a or b:
which side the robot plays in the policy's eyes), ``gc_team_number`` (the team's SPL number in gc/data),
``player_number`` (the robot's, 1 … 20), ``vision_hz`` and ``frames_per_period`` (the camera's rate and the motion
period in frames), ``params_file`` (e.g. the deployment profile config/deploy_policy_node.yaml; empty: none). The
node's topics are named for the policy's robot (``team_a_0/…``); the launch remaps each to the stack's own name in
the namespace (``REMAPPED``). Without ``launch`` (the PyPI wheels): the same node with ``-r`` remappings, as
docs/deploy.md shows.
"""
from __future__ import annotations

import sys
from pathlib import Path

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

ARGUMENTS = {"checkpoint": "", "team": "a", "gc_team_number": "1", "player_number": "1", "vision_hz": "10.0",
             "frames_per_period": "5", "params_file": ""}
# The node's topics, each named <robot>/NAME (dynenv_ros/ros/topics.py), that a team's stack has as NAME.
REMAPPED = ("soccer_vision_3d/balls", "soccer_vision_3d/robots", "soccer_vision_3d/goalposts",
            "soccer_vision_3d/markings", "soccer_vision_3d/field_boundary", "soccer_vision_3d/obstacles", "gc/data",
            "joint_states", "fallen", "pose_estimate", "cmd_vel", "motion/kick", "motion/head", "action")


def remappings(robot: str) -> list[tuple[str, str]]:
    return [(f"{robot}/{name}", name) for name in REMAPPED]


def shipped_policy() -> str:
    installed = Path(sys.prefix) / "share" / "dynenv_ros" / "pretrained" / "policy.onnx"
    return str(installed if installed.exists() else
               Path(__file__).resolve().parent.parent / "policy_node" / "pretrained" / "policy.onnx")


def _node(context, *args, **kwargs) -> list:
    value = {name: LaunchConfiguration(name).perform(context) for name in ARGUMENTS}
    team, number = value["team"], int(value["gc_team_number"])
    other = number + 1 if number < 254 else number - 1      # only this team's number matters (gc/data names both)
    parameters: list = [value["params_file"]] if value["params_file"] else []
    parameters.append({"interfaces": "ros_sports", "players_per_team": 1, "team": team,
                       "checkpoint": value["checkpoint"] or shipped_policy(),
                       "gc_team_number_a": number if team == "a" else other,
                       "gc_team_number_b": number if team == "b" else other,
                       "gc_player_number": int(value["player_number"]), "vision_hz": float(value["vision_hz"]),
                       "frames_per_period": int(value["frames_per_period"])})
    return [Node(package="dynenv_ros", executable="policy_node", name="policy_node", parameters=parameters,
                 remappings=remappings(f"team_{team}_0"), output="screen")]


def generate_launch_description() -> LaunchDescription:
    arguments = [DeclareLaunchArgument(name, default_value=default) for name, default in ARGUMENTS.items()]
    return LaunchDescription([*arguments, OpaqueFunction(function=_node)])
