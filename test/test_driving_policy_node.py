"""The policy node for driving (issue 14): DetectionArray messages packed into driving's padded layout (the env's
arrays for the same perception), a random-initialised driving policy exported to ONNX driving every car of a stepped
game (both action modes: every action accepted, none missing or refused), and a policy of the other scenario or
action mode refused with the reason."""
from __future__ import annotations

import numpy as np
import pytest
import torch
from dynenv_msgs.srv import LoadPolicy
from rclpy.exceptions import ParameterException
from rclpy.parameter import Parameter
from rclpy.time import Time

from dynenv_ros.agent.checkpoint import save_policy
from dynenv_ros.agent.export import export_onnx
from dynenv_ros.agent.network import DynEnvAgent
from dynenv_ros.driving.config import DrivingConfig
from dynenv_ros.driving.world import DrivingWorld
from dynenv_ros.envs.detection_messages import pack_messages
from dynenv_ros.envs.driving_observations import PaddedObservation
from dynenv_ros.nodes.sim_node import SimNode
from dynenv_ros.ros.conversions import detection_array
from policy_node.policy_node import PolicyNode
from operator_helpers import operator_params, signed_call
from ros_harness import spin_until


def test_driving_messages_pack_into_the_envs_padded_arrays():
    config = DrivingConfig(n_cars=3)
    world = DrivingWorld(config, seed=4)
    observations = PaddedObservation(config, "realistic")
    observations.reset(world)
    observations.initial()
    rng = np.random.default_rng(4)
    for _ in range(5):
        world.step([rng.integers(0, 3, 2) for _ in range(3)], on_frame=observations.on_frame)
    expected = observations.build_padded()
    expected = observations.arrays
    perception = observations._perceptions[-1]
    periods = [[detection_array(perception.of_view(i), robot_id=i, robot_name=f"car_{i}", episode_id=1,
                                motion_period=6, frame_index=0, frames_per_period=1, head_yaw=0.0,
                                fallen=bool(perception.ego[i, 6]), penalized=bool(perception.ego[i, 7]),
                                kicking=False, ball_owner=0, ball_owner_seconds=0.0,
                                game_seconds_remaining=float(world.time_remaining), stamp=Time(seconds=1))]
               for i in range(3)]
    layout = observations.layout
    got, dropped = pack_messages(periods, [tuple(expected["previous_action"][i]) for i in range(3)],
                                 layout.max_landmarks, layout.max_objects, spec=layout.spec)
    assert dropped == 0 and set(got) == set(layout.keys)
    for key in layout.keys:
        np.testing.assert_allclose(got[key], expected[key], rtol=0, atol=1e-5, err_msg=key)


def _game(make_node, executor, action_mode, **policy_params):
    sim = make_node(SimNode, parameter_overrides=[Parameter(k, value=v) for k, v in dict(
        scenario="driving", n_cars=2, seed=5, action_mode=action_mode, episode_seconds=3.0, auto_reset=False,
        publish_markers=False).items()])
    policy = make_node(PolicyNode, parameter_overrides=[Parameter(k, value=v) for k, v in dict(
        scenario="driving", n_cars=2, action_mode=action_mode, seed=1, **policy_params).items()])
    executor.add_node(sim)
    executor.add_node(policy)
    return sim, policy


@pytest.mark.parametrize("action_mode", ["discrete", "continuous"])
def test_an_exported_driving_policy_drives_every_car_without_a_refusal(make_node, executor, tmp_path, action_mode):
    torch.manual_seed(6)
    path = tmp_path / "drive.onnx"
    export_onnx(DynEnvAgent(feature_size=32, scenario="driving", action_mode=action_mode), path)
    sim, policy = _game(make_node, executor, action_mode, checkpoint=str(path), runtime="onnxruntime")
    assert policy.names == ["car_0", "car_1"]
    assert spin_until(executor, lambda: sim.session.finished, 60.0), dict(sim.session.counts)
    counts = sim.session.counts
    assert counts["accepted"] == 2 * 30 and counts["missing"] == 0, dict(counts)
    assert not any(k.startswith("rejected") and v for k, v in counts.items()), dict(counts)
    assert policy.counts["fallback_actions"] == 0 and policy.counts["failed_decisions"] == 0
    assert policy.counts["self_missing"] == 0 and all(m.state is not None for m in policy.memory.values())
    previous = [m.previous for m in policy.memory.values()]
    assert all(len(p) == 3 for p in previous)


def test_a_driving_safetensors_policy_plays_and_the_node_refuses_a_soccer_one(make_node, executor, tmp_path):
    torch.manual_seed(7)
    drive = tmp_path / "drive.safetensors"
    save_policy(DynEnvAgent(feature_size=16, scenario="driving"), drive)
    soccer = tmp_path / "soccer.safetensors"
    save_policy(DynEnvAgent(feature_size=16), soccer)
    continuous = tmp_path / "continuous.onnx"
    export_onnx(DynEnvAgent(feature_size=16, scenario="driving", action_mode="continuous"), continuous)
    sim, policy = _game(make_node, executor, "discrete", checkpoint=str(drive), **operator_params())
    assert spin_until(executor, lambda: sim.periods_run >= 3, 30.0), dict(sim.session.counts)

    def load(path, runtime):
        return signed_call(policy, executor, LoadPolicy, "/policy_node/load_policy",
                           LoadPolicy.Request(checkpoint_path=str(path), runtime=runtime))

    reply = load(soccer, "torch")
    assert not reply.success and "it is a soccer policy and this node plays driving" in reply.message, reply.message
    reply = load(continuous, "onnxruntime")
    assert not reply.success and "continuous driving policy" in reply.message, reply.message
    before = sim.periods_run
    assert spin_until(executor, lambda: sim.periods_run >= before + 2, 30.0)     # the driving policy kept playing
    assert not any(k.startswith("rejected") and v for k, v in sim.session.counts.items())


def test_a_soccer_node_refuses_a_driving_policy_at_start(make_node, tmp_path):
    drive = tmp_path / "drive.safetensors"
    save_policy(DynEnvAgent(feature_size=16, scenario="driving"), drive)
    with pytest.raises(ParameterException, match="it is a driving policy and this node plays soccer"):
        make_node(PolicyNode, parameter_overrides=[Parameter("checkpoint", value=str(drive)),
                                                   Parameter("players_per_team", value=1)])
    with pytest.raises(ParameterException, match="team applies to robocup"):
        make_node(PolicyNode, parameter_overrides=[Parameter("scenario", value="driving"),
                                                   Parameter("team", value="a")])


def test_a_policy_node_drives_its_cars_and_a_scripted_driver_the_others(make_node, executor, tmp_path):
    """``cars``: the policy node drives car_0 only and scripted_driver car_1 (the main job's driving graph with the
    shipped policy); every period both cars have an accepted action and nothing is refused. Unknown cars, and
    ``cars`` on a soccer node, are refused naming the parameter."""
    from rclpy.exceptions import ParameterException
    from policy_node.scripted_driver import ScriptedDriverNode
    torch.manual_seed(8)
    drive = tmp_path / "drive.safetensors"
    save_policy(DynEnvAgent(feature_size=16, scenario="driving"), drive)
    sim, policy = _game(make_node, executor, "discrete", checkpoint=str(drive), cars=["car_0"])
    driver = make_node(ScriptedDriverNode, parameter_overrides=[Parameter(k, value=v) for k, v in dict(
        n_cars=2, action_mode="discrete", cars=["car_1"]).items()])
    executor.add_node(driver)
    assert policy.names == ["car_0"] and driver.cars == ["car_1"]
    assert spin_until(executor, lambda: sim.session.finished, 60.0), dict(sim.session.counts)
    counts = sim.session.counts
    assert counts["accepted"] == 2 * 30 and counts["missing"] == 0, dict(counts)
    assert not any(k.startswith("rejected") and v for k, v in counts.items()), dict(counts)
    for params, words in ((dict(scenario="driving", n_cars=2, cars=["car_7"]), r"unknown cars \['car_7'\]"),
                          (dict(players_per_team=1, cars=["car_0"]), "cars is a driving parameter")):
        with pytest.raises(ParameterException, match=words):
            make_node(PolicyNode, parameter_overrides=[Parameter(k, value=v) for k, v in params.items()])
