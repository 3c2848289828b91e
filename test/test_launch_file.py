"""launch/dynenv.launch.py, for users with a full ROS 2 install, mirrors the main job's graph node for node. The
PyPI wheels this project runs on have no `launch`, so its structure is tested with stand-ins for the few launch
classes it uses: the nodes it would start are exactly the main job's (name, executable, parameters), each
executable is one of the package's console scripts, and the simulator's exit ends the launch."""
from __future__ import annotations

import importlib.util
import re
import sys
import types
from pathlib import Path

import pytest

from dynenv_ros.main_job import default_config_path, load_config, soccer_graph

REPO = Path(__file__).resolve().parent.parent
LAUNCH_FILE = REPO / "launch" / "dynenv.launch.py"


class _Recorded:
    def __init__(self, *args, **kwargs) -> None:
        self.args, self.kwargs = args, kwargs


class _Configuration:
    def __init__(self, name: str) -> None:
        self.name = name

    def perform(self, context) -> str:
        return context[self.name]


@pytest.fixture
def launch_module(monkeypatch):
    return _import_launch(monkeypatch, LAUNCH_FILE)


def _import_launch(monkeypatch, path: Path):
    """A launch file imported with stand-ins for launch and launch_ros (whatever of them is installed is hidden)."""
    stand_ins = {"launch": {"LaunchDescription": _Recorded},
                 "launch.actions": {"DeclareLaunchArgument": _Recorded, "OpaqueFunction": _Recorded,
                                    "Shutdown": _Recorded},
                 "launch.substitutions": {"LaunchConfiguration": _Configuration},
                 "launch_ros": {}, "launch_ros.actions": {"Node": _Recorded}}
    for name, members in stand_ins.items():
        module = types.ModuleType(name)
        module.__dict__.update(members)
        monkeypatch.setitem(sys.modules, name, module)
    spec = importlib.util.spec_from_file_location(path.stem.replace(".", "_"), path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _launched(module, tmp_path, **arguments) -> tuple[list, dict]:
    description = module.generate_launch_description()
    entities = description.args[0]
    declared = {e.args[0]: e.kwargs["default_value"] for e in entities if isinstance(e, _Recorded) and e.args}
    context = {**declared, "run_dir": str(tmp_path), **arguments}
    opaque = entities[-1]
    return opaque.kwargs["function"](context), declared


@pytest.mark.parametrize("arguments, overrides", [
    ({}, {}),
    ({"scenario": "driving", "n_cars": "3"}, {"scenario": "driving", "n_cars": 3}),
    ({"set": "team_a=scripted policy=perceiving duration_s=30"},
     {"team_a": "scripted", "policy": "perceiving", "duration_s": 30}),
    ({"set": "interfaces=ros_sports policy=perceiving"}, {"interfaces": "ros_sports", "policy": "perceiving"}),
])
def test_the_launch_file_starts_the_main_jobs_graph_node_for_node(launch_module, tmp_path, arguments, overrides):
    nodes, declared = _launched(launch_module, tmp_path, **arguments)
    expected = soccer_graph(load_config(default_config_path(), overrides), tmp_path)
    assert [n.kwargs["name"] for n in nodes] == [e.name for e in expected]
    scripts = dict(re.findall(r'"(\w+) = ([\w.]+):main"', (REPO / "setup.py").read_text()))
    for node, node_spec in zip(nodes, expected):
        assert node.kwargs["package"] == "dynenv_ros"
        assert scripts[node.kwargs["executable"]] == node_spec.module      # the same program as the main job's
        assert node.kwargs["parameters"] == [node_spec.parameters]
        assert (node.kwargs["remappings"] or []) == list(node_spec.remaps.items())    # ros_sports: policy_action
        assert (node.kwargs["on_exit"] is not None) == node_spec.ends_run   # the simulator's exit ends the launch
    assert {"scenario", "seed", "duration_s", "players_per_team", "n_cars", "config", "run_dir", "set"} <= set(declared)


def test_a_bad_setting_is_refused_as_the_main_job_refuses_it(launch_module, tmp_path):
    from dynenv_ros.main_job import ConfigError
    with pytest.raises(ConfigError, match="players_per_team must be in"):
        _launched(launch_module, tmp_path, players_per_team="9")


def test_the_launch_file_is_installed_with_the_package():
    assert 'glob("launch/*.launch.py")' in (REPO / "setup.py").read_text()


def test_the_ros_sports_launch_file_starts_a_policy_node_on_a_stacks_topics(monkeypatch, tmp_path, make_node):
    """launch/ros_sports_policy.launch.py: the executable is the package's policy node, every parameter it sets is
    one the node declares with interfaces:=ros_sports, and every remapping names a topic the node has."""
    from rclpy.parameter import Parameter

    from dynenv_ros.graph.inventory import observe
    from policy_node.policy_node import PolicyNode
    module = _import_launch(monkeypatch, REPO / "launch" / "ros_sports_policy.launch.py")
    description = module.generate_launch_description()
    entities = description.args[0]
    declared = {e.args[0]: e.kwargs["default_value"] for e in entities if isinstance(e, _Recorded) and e.args}
    (node,) = entities[-1].kwargs["function"]({**declared, "gc_team_number": "12", "player_number": "3"})
    scripts = dict(re.findall(r'"(\w+) = ([\w.]+):main"', (REPO / "setup.py").read_text()))
    assert scripts[node.kwargs["executable"]] == "policy_node.policy_node"
    (parameters,) = node.kwargs["parameters"]
    assert (parameters["gc_team_number_a"], parameters["gc_player_number"], parameters["team"]) == (12, 3, "a")
    assert Path(parameters["checkpoint"]).is_file()
    policy = make_node(PolicyNode, parameter_overrides=[Parameter(k, value=v) for k, v in parameters.items()])
    seen = observe(policy)
    topics = seen["publishes"] | seen["subscribes"]
    for source, target in node.kwargs["remappings"]:
        assert source.replace("team_a_0", "<robot>") in {t.lstrip("/") for t in topics}, source
        assert target == source.split("/", 1)[1]
    assert {"/<robot>/soccer_vision_3d/balls", "/<robot>/gc/data", "/<robot>/cmd_vel"} <= topics
