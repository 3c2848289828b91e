"""The ROS inventory (issue 43 item 1): every node started in-process with its defaults (and the security options
on, so every entry shows) offers exactly the services, topics and parameters the committed table classifies, and
docs/ros_graph.md holds the table as generated."""
from __future__ import annotations

import os
from pathlib import Path

import pytest
from rclpy.parameter import Parameter

from dynenv_ros.graph.inventory import differences, observe, render
from dynenv_ros.graph.inventory_table import CLASSES, NODES
from dynenv_ros.security.action_auth import secret_path, write_game_secrets, write_team_secret
from dynenv_ros.security.frame_auth import FRAMES
from dynenv_ros.soccer.config import robot_names

DOC = Path(__file__).resolve().parents[1] / "docs" / "ros_graph.md"
SHIPPED = Path(__file__).resolve().parents[1] / "policy_node" / "pretrained" / "policy.onnx"   # takes the pose
BEGIN, END = "<!-- inventory:begin -->\n", "<!-- inventory:end -->\n"


# This module's nodes run on a ROS domain of their own: the worker's (test/conftest.py: 1..100) + 100.
OWN_DOMAIN_OFFSET = 100


@pytest.fixture
def ros_context():
    """test/conftest.py's context, on a domain no other test uses. The graph API answers for a node *name*, so a
    same-named node of another test (a half-built one not yet collected, a killed process's until its lease runs
    out) answered in this node's place, and the recorder and the trainer subscribe to the robots' topics they find
    on the graph: each test here must see its one node on an empty graph."""
    import rclpy
    from rclpy.context import Context

    context = Context()
    rclpy.init(context=context, domain_id=int(os.environ["ROS_DOMAIN_ID"]) + OWN_DOMAIN_OFFSET)
    yield context
    rclpy.try_shutdown(context=context)


def _params(**values):
    return [Parameter(k, value=v) for k, v in values.items()]


def _start(name: str, make_node, tmp_path: Path):
    from weights_helpers import key_pair
    from dynenv_ros.nodes.motion_emulator import MotionEmulator
    from dynenv_ros.nodes.recorder import Recorder
    from dynenv_ros.nodes.sim_node import SimNode
    from dynenv_ros.nodes.trainer_node import TrainerNode
    from dynenv_ros.nodes.vision_adapter import VisionAdapter
    from policy_node.perceiving_policy import PerceivingPolicyNode
    from policy_node.policy_node import PolicyNode
    from policy_node.scripted_driver import ScriptedDriverNode
    from policy_node.scripted_policy import ScriptedPolicyNode
    secrets = write_game_secrets(tmp_path / "secrets", robot_names(1))
    write_team_secret(secret_path(secrets, FRAMES))
    private, public = key_pair(tmp_path / "keys")
    secure = dict(secrets_dir=str(secrets), authenticated_frames=True)
    starts = {
        "sim_node": (SimNode, _params(players_per_team=1, wait_for_subscribers=0, **secure)),
        "sim_node ros_sports": (SimNode, _params(players_per_team=1, wait_for_subscribers=0, ros_sports=True,
                                                 **secure)),
        "policy_node": (PolicyNode, _params(players_per_team=1, trusted_operator_keys=[str(public)], **secure)),
        "policy_node ros_sports": (PolicyNode, _params(players_per_team=1, trusted_operator_keys=[str(public)],
                                                       secrets_dir=str(secrets), interfaces="ros_sports",
                                                       checkpoint=str(SHIPPED))),
        "motion_emulator": (MotionEmulator, _params(players_per_team=1, secrets_dir=str(secrets))),
        "trainer_node": (TrainerNode, _params(players_per_team=1, run_dir=str(tmp_path / "run"),
                                              signing_key=str(private), feature_size=16, **secure)),
        "scripted_policy": (ScriptedPolicyNode, []), "perceiving_policy": (PerceivingPolicyNode, []),
        "scripted_driver": (ScriptedDriverNode, []), "vision_adapter": (VisionAdapter, []),
        "recorder": (Recorder, _params(output=str(tmp_path / "bag")))}
    node_class, parameters = starts[name]
    return make_node(node_class, parameter_overrides=parameters)


@pytest.mark.parametrize("name", NODES)
def test_every_service_topic_and_parameter_of_a_node_has_a_class(name, make_node, tmp_path):
    node = _start(name, make_node, tmp_path)
    assert node.context.get_domain_id() == int(os.environ["ROS_DOMAIN_ID"]) + OWN_DOMAIN_OFFSET
    observed = observe(node)
    assert observed["parameters"] and observed["publishes"]          # the graph API saw the node
    assert differences(name, observed) == []


def test_a_new_service_topic_or_parameter_without_a_class_fails_the_inventory(make_node, tmp_path):
    from dynenv_msgs.msg import Action
    from dynenv_msgs.srv import StepSimulation      # any service type: the project's own, no extra dependency
    node = _start("policy_node", make_node, tmp_path)
    assert differences("policy_node", observe(node)) == []
    node.create_service(StepSimulation, "~/open_door", lambda request, response: response)
    node.create_publisher(Action, "/team_a_0/side_door", 10)
    node.create_subscription(Action, "~/back_door", lambda _: None, 10)
    node.declare_parameter("new_knob", 1)
    assert sorted(differences("policy_node", observe(node))) == sorted(
        f"policy_node {entry}: no class (add it to dynenv_ros/graph/inventory_table.py)"
        for entry in ("services ~/open_door", "publishes /<robot>/side_door", "subscribes ~/back_door",
                      "parameters new_knob"))


def test_the_docs_hold_the_generated_table():
    text = DOC.read_text()
    assert BEGIN in text and END in text
    assert text.split(BEGIN, 1)[1].split(END, 1)[0] == render()
    assert set(CLASSES) == set(NODES)
