"""The policy node closes the loop with the simulator node in stepped mode, keeps per-robot state, and loads
checkpoints safely (a bad one is refused and the current policy keeps playing)."""
from __future__ import annotations

import torch
from dynenv_msgs.srv import LoadPolicy
from rclpy.parameter import Parameter

from dynenv_ros.nodes.sim_node import SimNode
from dynenv_ros.agent.checkpoint import save_policy
from dynenv_ros.agent.network import DynEnvAgent
from policy_node.policy_node import PolicyNode
from operator_helpers import operator_params, signed_call
from ros_harness import spin_until


def _graph(make_node, executor, **policy_params):
    sim = make_node(SimNode, parameter_overrides=[Parameter(k, value=v) for k, v in dict(
        players_per_team=1, seed=3, falls_enabled=False, publish_markers=False).items()])
    policy = make_node(PolicyNode, parameter_overrides=[Parameter(k, value=v) for k, v in dict(
        players_per_team=1, seed=1, **operator_params(), **policy_params).items()])
    executor.add_node(sim)
    executor.add_node(policy)
    return sim, policy


def test_the_policy_node_drives_every_robot_through_the_simulator(make_node, executor):
    sim, policy = _graph(make_node, executor)
    assert spin_until(executor, lambda: sim.periods_run >= 4, 30.0), sim.session.counts
    assert sim.session.counts["accepted"] >= 8 and sim.session.counts["missing"] == 0
    assert not any(v for k, v in sim.session.counts.items() if k.startswith("rejected"))
    assert policy.actions_sent >= 8 and all(m.state is not None for m in policy.memory.values())
    assert len(policy.latencies_ms) >= 4 and min(policy.latencies_ms) > 0      # latency is reported (figures: bench)


def test_one_team_per_policy_node_so_two_policies_can_play(make_node, executor):
    sim = make_node(SimNode, parameter_overrides=[Parameter("players_per_team", value=1),
                                                  Parameter("falls_enabled", value=False)])
    a = make_node(PolicyNode, parameter_overrides=[Parameter("players_per_team", value=1),
                                                   Parameter("team", value="a")])
    b = make_node(PolicyNode, parameter_overrides=[Parameter("players_per_team", value=1),
                                                   Parameter("team", value="b"), Parameter("seed", value=5)])
    for node in (sim, a, b):
        executor.add_node(node)
    assert a.names == ["team_a_0"] and b.names == ["team_b_0"]
    assert spin_until(executor, lambda: sim.periods_run >= 3, 30.0)
    assert a.actions_sent >= 3 and b.actions_sent >= 3


def test_checkpoints_load_and_bad_ones_are_refused(make_node, executor, tmp_path):
    torch.manual_seed(4)
    good = tmp_path / "agent.safetensors"
    digest = save_policy(DynEnvAgent(), good)
    bad = tmp_path / "bad.pt"
    bad.write_bytes(b"not a checkpoint")
    sim, policy = _graph(make_node, executor, checkpoint=str(good))
    assert policy.checkpoint_sha256 == digest

    def load(path):
        return signed_call(policy, executor, LoadPolicy, "/policy_node/load_policy",
                           LoadPolicy.Request(checkpoint_path=str(path), runtime="torch"))

    reply = load(bad)
    assert not reply.success and "kept the current policy" in reply.message and "cannot be read safely" in reply.message
    assert policy.checkpoint_sha256 == digest
    reply = load(good)
    assert reply.success and reply.checkpoint_sha256 == digest
    before = sim.periods_run
    assert spin_until(executor, lambda: sim.periods_run >= before + 2, 30.0)    # still playing after the swap


def test_an_exported_onnx_policy_plays_and_can_be_swapped_in(make_node, executor, tmp_path):
    from dynenv_ros.agent.export import export_onnx
    torch.manual_seed(6)
    onnx_file = tmp_path / "agent.onnx"
    export_onnx(DynEnvAgent(), onnx_file)
    sim, policy = _graph(make_node, executor, checkpoint=str(onnx_file), runtime="onnxruntime")
    assert spin_until(executor, lambda: sim.periods_run >= 3, 30.0), sim.session.counts
    assert policy.actions_sent >= 6 and not any(v for k, v in sim.session.counts.items() if k.startswith("rejected"))


def test_swapping_in_a_network_of_another_size_keeps_playing(make_node, executor, tmp_path):
    torch.manual_seed(7)
    smaller = tmp_path / "small.safetensors"
    save_policy(DynEnvAgent(feature_size=16), smaller)
    sim, policy = _graph(make_node, executor)
    assert spin_until(executor, lambda: sim.periods_run >= 2, 30.0)
    assert signed_call(policy, executor, LoadPolicy, "/policy_node/load_policy",
                       LoadPolicy.Request(checkpoint_path=str(smaller), runtime="torch")).success
    before = sim.periods_run
    assert spin_until(executor, lambda: sim.periods_run >= before + 2, 30.0)


def test_the_runtime_is_inferred_from_the_policy_file(make_node, executor, tmp_path):
    """Issue 28: an .onnx checkpoint without runtime:=onnxruntime was refused; the runtime now comes from the file
    (.onnx: onnxruntime, else torch), at start and in LoadPolicy with an empty runtime, while an explicit runtime
    that does not fit the file is still refused with the reason."""
    from dynenv_ros.agent.checkpoint import save_policy
    from dynenv_ros.agent.export import export_onnx
    torch.manual_seed(6)
    onnx_file, torch_file = tmp_path / "agent.onnx", tmp_path / "agent.safetensors"
    export_onnx(DynEnvAgent(), onnx_file)
    save_policy(DynEnvAgent(), torch_file)
    sim, policy = _graph(make_node, executor, checkpoint=str(onnx_file))
    assert policy.runtime_name == "onnxruntime"
    assert spin_until(executor, lambda: sim.periods_run >= 2, 30.0), sim.session.counts

    def load(path, runtime=""):
        return signed_call(policy, executor, LoadPolicy, "/policy_node/load_policy",
                           LoadPolicy.Request(checkpoint_path=str(path), runtime=runtime))

    reply = load(torch_file)
    assert reply.success and policy.runtime_name == "torch", reply.message
    reply = load(onnx_file, "torch")
    assert not reply.success and "is an ONNX file: load it with runtime onnxruntime" in reply.message
    assert load(onnx_file).success and policy.runtime_name == "onnxruntime"
    before = sim.periods_run
    assert spin_until(executor, lambda: sim.periods_run >= before + 2, 30.0)
