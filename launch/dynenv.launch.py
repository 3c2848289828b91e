"""The main job's graphs for users with a full ROS 2 install (``ros2 launch``), node for node: the launch file asks
``dynenv_ros.main_job`` for the graph (``soccer_graph``: the soccer game, or with ``scenario:=driving`` the driving
one) and starts each of its nodes as the package's executable, with the same names and parameters, so the two
cannot drift apart. The run ends when the simulator exits (``ends_run`` in the main job).

    ros2 launch dynenv_ros dynenv.launch.py
    ros2 launch dynenv_ros dynenv.launch.py scenario:=driving n_cars:=3 run_dir:=/tmp/drive
    ros2 launch dynenv_ros dynenv.launch.py set:="duration_s=30 team_a=scripted policy=perceiving"
    ros2 launch dynenv_ros dynenv.launch.py set:="interfaces=ros_sports policy=perceiving"

Launch arguments: ``config`` (a main-job YAML, default the package's config/main_job.yaml), ``run_dir`` (where the
simulator's report and the bag go, default runs/launch-<time>), ``set`` (space-separated KEY=VALUE overrides of the
main-job settings, as ``dynenv-run --set``), and the common settings directly: ``scenario``, ``seed``,
``duration_s``, ``players_per_team``, ``n_cars``. The venv equivalent, without ``launch``: ``make run`` /
``.venv/bin/dynenv-run`` (the main job), which also prints the summary and checks the bag.
"""
from __future__ import annotations

import time
from pathlib import Path

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, OpaqueFunction, Shutdown
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

COMMON = {"scenario": "robocup", "seed": "0", "duration_s": "60.0", "players_per_team": "2", "n_cars": "2"}
# module of a graph node -> the package's executable (setup.py's console_scripts)
EXECUTABLES = {"dynenv_ros.nodes.sim_node": "sim_node", "dynenv_ros.nodes.recorder": "recorder",
               "policy_node.policy_node": "policy_node", "policy_node.scripted_policy": "scripted_policy",
               "policy_node.perceiving_policy": "perceiving_policy", "policy_node.scripted_driver": "scripted_driver",
               "dynenv_ros.nodes.trainer_node": "trainer_node", "dynenv_ros.nodes.vision_adapter": "vision_adapter",
               "dynenv_ros.nodes.motion_emulator": "motion_emulator"}


def _nodes(context, *args, **kwargs) -> list:
    import yaml
    from dynenv_ros.main_job import default_config_path, load_config, soccer_graph
    value = {name: LaunchConfiguration(name).perform(context) for name in (*COMMON, "config", "run_dir", "set")}
    overrides = {name: yaml.safe_load(value[name]) for name in COMMON if value[name] != COMMON[name]}
    for pair in value["set"].split():
        key, _, text = pair.partition("=")
        overrides[key] = yaml.safe_load(text)
    config = load_config(Path(value["config"]) if value["config"] else default_config_path(), overrides)
    run_dir = Path(value["run_dir"] or f"runs/launch-{time.strftime('%Y%m%d-%H%M%S')}")
    run_dir.mkdir(parents=True, exist_ok=True)
    actions = []
    for node in soccer_graph(config, run_dir):
        actions.append(Node(package="dynenv_ros", executable=EXECUTABLES[node.module], name=node.name,
                            namespace=node.namespace or None, parameters=[dict(node.parameters)], output="screen",
                            remappings=list(node.remaps.items()) or None,
                            on_exit=Shutdown() if node.ends_run else None))
    return actions


def generate_launch_description() -> LaunchDescription:
    arguments = [DeclareLaunchArgument(name, default_value=default) for name, default in COMMON.items()]
    arguments += [DeclareLaunchArgument("config", default_value=""), DeclareLaunchArgument("run_dir", default_value=""),
                  DeclareLaunchArgument("set", default_value="")]
    return LaunchDescription([*arguments, OpaqueFunction(function=_nodes)])
