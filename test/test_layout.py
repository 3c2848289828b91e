"""What importing loads, which the import graph cannot tell.

The layers themselves (no upward import, no import cycle, no ROS in the ROS-free packages, ray in three modules
only) are import-linter contracts in .importlinter, checked by ``make lint`` before the suite; they count imports
inside functions too. These tests run the imports: the light packages must load neither ROS nor torch (an
environment process stays small), and the trainer and the ROS graph must start without Ray (imported lazily, only
by the Ray back end); the policy node's ROS-free core must load no ROS either. And the one size rule: no module of
policy_node/ is longer than 300 lines (issue 40's thin nodes)."""
from __future__ import annotations

import pkgutil
import subprocess
import sys

import pytest

import dynenv_ros.bags
import dynenv_ros.core
import dynenv_ros.envs
import dynenv_ros.evaluation
import dynenv_ros.perception
import dynenv_ros.render
import dynenv_ros.sim
import dynenv_ros.soccer

LIGHT_PACKAGES = [dynenv_ros.core, dynenv_ros.bags, dynenv_ros.sim, dynenv_ros.soccer, dynenv_ros.envs,
                  dynenv_ros.render, dynenv_ros.perception, dynenv_ros.evaluation]


def test_the_light_packages_load_neither_ros_nor_torch():
    modules = [f"{pkg.__name__}.{info.name}" for pkg in LIGHT_PACKAGES
               for info in pkgutil.iter_modules(pkg.__path__)]
    assert modules, "no modules found to check"
    probe = (f"import sys\nfor m in {modules!r}: __import__(m)\n"
             "bad = sorted(m for m in sys.modules if m.split('.')[0] in ('rclpy', 'dynenv_msgs', 'rosidl_parser', 'torch'))\n"
             "print(bad)")
    result = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, check=True)
    assert result.stdout.strip() == "[]", result.stdout


@pytest.mark.ros   # its probe process imports the nodes, which load rclpy
def test_the_trainer_and_the_ros_graph_import_without_ray():
    probe = ("import sys\nimport dynenv_ros.learning.trainer, dynenv_ros.learning.distributed.pool_source, "
             "dynenv_ros.learning.train_cli, dynenv_ros.nodes.trainer_node, "
             "dynenv_ros.nodes.sim_node\n"
             "print(sorted(m for m in sys.modules if m.split('.')[0] == 'ray'))")
    result = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, check=True)
    assert result.stdout.strip() == "[]", result.stdout


def test_every_policy_node_module_is_at_most_300_lines():
    """Issue 40: the policy node is a thin adapter over a ROS-free core, one concept per module; none of
    policy_node/'s modules grows past 300 lines (policy_node.py was 864)."""
    from pathlib import Path
    folder = Path(__file__).resolve().parents[1] / "policy_node"
    lengths = {path.name: len(path.read_text().splitlines()) for path in sorted(folder.glob("*.py"))}
    assert "policy_node.py" in lengths and "decider.py" in lengths, sorted(lengths)
    assert {name: n for name, n in lengths.items() if n > 300} == {}


def test_the_policy_nodes_decider_core_loads_no_ros():
    """The decider and what it runs import without rclpy or any message package (what importing loads; the import
    graph's contract in .importlinter says the same of their imports)."""
    core = ["policy_node.decider", "policy_node.batch_policy", "policy_node.policy_files", "policy_node.periods",
            "policy_node.partial_periods"]
    probe = (f"import sys\nfor m in {core!r}: __import__(m)\n"
             "print(sorted(m for m in sys.modules if m.split('.')[0] in ('rclpy', 'dynenv_msgs', 'rosidl_parser', "
             "'geometry_msgs', 'builtin_interfaces', 'std_msgs') or m.startswith('dynenv_ros.ros')))")
    result = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, check=True)
    assert result.stdout.strip() == "[]", result.stdout
