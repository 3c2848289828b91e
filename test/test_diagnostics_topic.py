"""Issue 28: every node reports on /diagnostics, the topic diagnostic_aggregator and rqt_robot_monitor read, each
status named after the node's fully qualified name (the nodes' own diagnostics topics stay as they were)."""
from __future__ import annotations

from pathlib import Path

from diagnostic_msgs.msg import DiagnosticArray
from rclpy.parameter import Parameter
from rclpy.qos import QoSProfile

from weights_helpers import key_pair

REPO = Path(__file__).resolve().parent.parent


def _params(**values) -> list[Parameter]:
    return [Parameter(k, value=v) for k, v in values.items()]


def test_every_node_publishes_its_diagnostics_on_the_standard_topic(make_node, executor, tmp_path):
    from dynenv_ros.nodes.bag_player import BagPlayer
    from dynenv_ros.nodes.recorder import Recorder
    from dynenv_ros.nodes.selfcheck_listener import SelfCheckListener
    from dynenv_ros.nodes.selfcheck_talker import SelfCheckTalker
    from dynenv_ros.nodes.sim_node import SimNode
    from dynenv_ros.nodes.trainer_node import TrainerNode
    from dynenv_ros.nodes.vision_adapter import VisionAdapter
    from policy_node.perceiving_policy import PerceivingPolicyNode
    from policy_node.policy_node import PolicyNode
    from policy_node.scripted_driver import ScriptedDriverNode
    from policy_node.scripted_policy import ScriptedPolicyNode
    seen: dict[str, DiagnosticArray] = {}
    watcher = make_node("diagnostics_watcher")
    watcher.create_subscription(DiagnosticArray, "/diagnostics",
                                lambda msg: [seen.setdefault(s.name.split(":")[0], msg) for s in msg.status],
                                QoSProfile(depth=100))
    executor.add_node(watcher)
    private, _ = key_pair(tmp_path / "keys")
    nodes = [
        make_node(SimNode, parameter_overrides=_params(players_per_team=1, publish_markers=False)),
        make_node(PolicyNode, parameter_overrides=_params(players_per_team=1, team="a")),
        make_node(ScriptedPolicyNode, parameter_overrides=_params(robot="team_b_0")),
        make_node(PerceivingPolicyNode, parameter_overrides=_params(robot="team_b_0", players_per_team=1)),
        make_node(ScriptedDriverNode, parameter_overrides=_params(n_cars=1)),
        make_node(Recorder, exit_when_done=False, parameter_overrides=_params(output=str(tmp_path / "bag"))),
        make_node(BagPlayer, exit_when_done=False,
                  parameter_overrides=_params(bag=str(REPO / "bags" / "sample_2v2_realistic_30s"))),
        make_node(TrainerNode, parameter_overrides=_params(players_per_team=1, variant="baseline", feature_size=16,
                                                            run_dir=str(tmp_path / "run"), signing_key=str(private))),
        make_node(VisionAdapter, parameter_overrides=_params(players_per_team=1)),
        make_node(SelfCheckTalker), make_node(SelfCheckListener),
    ]
    for node in nodes:
        executor.add_node(node)
    names = {node.get_fully_qualified_name() for node in nodes}
    assert len(names) == len(nodes)
    import time
    from dynenv_ros.ros.node_runner import NodeExit
    deadline = time.monotonic() + 30.0
    while not names <= set(seen) and time.monotonic() < deadline:
        try:
            executor.spin_once(timeout_sec=0.05)
        except NodeExit:       # the selfcheck listener ends its run once every interface checked out
            pass
    assert names <= set(seen), sorted(names - set(seen))
    for name in names:
        assert all(s.hardware_id for s in seen[name].status)
