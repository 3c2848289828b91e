"""The trainer node learning driving (``scenario:=driving``) over a live graph, launch-free: it finds the cars by
name, rebuilds exactly what the driving policy node saw and chose (both action modes), streams weights the policy
node swaps in, and refuses the parameters of the other scenario with the reason."""
from __future__ import annotations

import pytest
from rclpy.exceptions import ParameterException
from rclpy.parameter import Parameter

from dynenv_ros.nodes.sim_node import SimNode
from dynenv_ros.nodes.trainer_node import TrainerNode
from policy_node.policy_node import PolicyNode
from ros_harness import spin_until
from weights_helpers import key_pair

TRAINER = dict(scenario="driving", n_cars=2, sequence_length=4, batch_sequences=2, ppo_epochs=1, ppo_minibatches=1,
               feature_size=16, variant="pred")


def _params(**values):
    return [Parameter(k, value=v) for k, v in values.items()]


def _driving_graph(make_node, executor, tmp_path, action_mode, **trainer_values):
    """The trainer, then a stepped 2-car game (2 s episodes) whose policy node drives both cars with the trainer's
    weights; the game starts once the policy node and the trainer read every car's detections."""
    private, public = key_pair(tmp_path / "keys")
    trainer = make_node(TrainerNode, parameter_overrides=_params(
        **{**TRAINER, "action_mode": action_mode, "run_dir": str(tmp_path / "run"), "signing_key": str(private),
           **trainer_values}))
    policy = make_node(PolicyNode, parameter_overrides=_params(scenario="driving", n_cars=2, action_mode=action_mode,
                                                               seed=5, trusted_weights_keys=[str(public)]))
    executor.add_node(trainer)
    executor.add_node(policy)
    # the trainer's first weights act from the first period (fetched: a round trip or two before the game starts)
    assert spin_until(executor, lambda: policy.weights_acting is not None, 60.0), policy.counts
    sim = make_node(SimNode, parameter_overrides=_params(
        scenario="driving", n_cars=2, action_mode=action_mode, seed=4, episode_seconds=2.0, publish_markers=False,
        wait_for_subscribers=2))
    executor.add_node(sim)
    return trainer, sim, policy


@pytest.mark.parametrize("action_mode", ["discrete", "continuous"])
def test_the_trainer_rebuilds_what_the_driving_policy_saw_and_chose(make_node, executor, tmp_path, action_mode):
    """With the learning rate at 0 every version's weights are the first ones, so the learner's log-probability of
    each action rebuilt from the wire equals the one the policy node sent: the cars' frames, previous commands,
    recurrent state and actions (indices, or normalised commands — those on a bound scored as the mass beyond it)
    mean what the policy saw."""
    trainer, sim, policy = _driving_graph(make_node, executor, tmp_path, action_mode, learning_rate=1e-7)
    for group in trainer.message_trainer.optimizer.param_groups:
        group["lr"] = 0.0
    assert spin_until(executor, lambda: trainer.message_trainer.progress.updates >= 3
                      and "behaviour_log_prob_error" in trainer.message_trainer.last_stats, 120.0), trainer.diagnostics()
    stats = trainer.message_trainer.last_stats
    assert stats["behaviour_log_prob_error"] < 1e-3, stats
    counts = trainer.assembler.counts
    assert counts["missing"] == 0 and counts["malformed"] == 0 and counts["late"] == 0, counts
    assert counts["actions_rounded"] == 0, counts
    assert trainer.readers.games == {""} and {r for _, r in trainer.readers.robots} == {"car_0", "car_1"}
    assert trainer.message_trainer.agent.scenario == "driving" and not trainer.background.error


def test_driving_weights_flow_back_and_the_policy_drives_with_new_versions(make_node, executor, tmp_path):
    trainer, sim, policy = _driving_graph(make_node, executor, tmp_path, "continuous", learning_rate=1e-3,
                                          max_policy_lag=2)
    # a policy node of the other action mode (in a namespace of its own, no game) gets the same weights
    other = make_node(PolicyNode, namespace="/other", parameter_overrides=_params(
        scenario="driving", n_cars=2, trusted_weights_keys=[str(tmp_path / "keys" / "trainer.pub")]))
    executor.add_node(other)
    assert spin_until(executor, lambda: policy.policy_version >= 3, 120.0), (policy.policy_version, policy.counts,
                                                                          trainer.diagnostics())
    assert policy.weights_acting[0] == trainer.run_id and policy.counts["weights_refused"] == 0
    assert spin_until(executor, lambda: other.counts["weights_refused"] >= 1, 10.0), other.counts
    assert "continuous driving policy" in other.weights_refusal and other.policy_version == 0
    assert other.counts["weights_refused_wrong_network"] >= 1          # refused before anything was fetched
    assert trainer.message_trainer.agent.action_mode == "continuous" and trainer.message_trainer.last_stats["lag_versions_max"] <= 2
    periods = sim.periods_run
    assert spin_until(executor, lambda: sim.periods_run >= periods + 5, 30.0)     # still driving on new weights
    assert not any(k.startswith("rejected") and v for k, v in sim.session.counts.items()), dict(sim.session.counts)
    trainer.destroy_node()                            # finishes the run directory
    from dynenv_ros.agent.checkpoint import load_policy
    agent, _ = load_policy(tmp_path / "run" / "policy.safetensors")
    assert agent.scenario == "driving" and agent.action_mode == "continuous"


@pytest.mark.parametrize("scenario, values, refused", [
    ("driving", {"players_per_team": 2}, "players_per_team: a parameter of scenario 'robocup'"),
    ("driving", {"learning_team": "a"}, "learning_team: a parameter of scenario 'robocup'"),
    ("robocup", {"n_cars": 3}, "n_cars: a parameter of scenario 'driving'"),
    ("robocup", {"action_mode": "continuous"}, "action_mode: a parameter of scenario 'driving'"),
    ("driving", {"variant": "recon"}, "variant: 'recon' is soccer-only"),
    ("flying", {}, "'flying' is not one of: robocup, driving"),
])
def test_parameters_of_the_other_scenario_are_refused_with_the_reason(make_node, tmp_path, scenario, values, refused):
    params = {"scenario": scenario, "run_dir": str(tmp_path / "run"), **values}
    with pytest.raises(ParameterException, match=refused):
        make_node(TrainerNode, parameter_overrides=_params(**params))
