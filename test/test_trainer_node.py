"""The trainer node over a live graph, launch-free: it finds the games' robots by name, learns from what the policy
nodes did (and rebuilds exactly what they saw), streams weights the policy nodes swap in, and keeps several games
apart."""
from __future__ import annotations

import json
from pathlib import Path

import pytest
from rclpy.parameter import Parameter

from dynenv_ros.nodes.sim_node import SimNode
from dynenv_ros.nodes.trainer_node import TrainerNode
from policy_node.policy_node import PolicyNode
from operator_helpers import operator_params
from ros_harness import spin_until
from weights_helpers import key_pair


def _params(**values):
    return [Parameter(k, value=v) for k, v in values.items()]


def _game(make_node, executor, namespace=None, seed=3, trusted=None):
    """A stepped 1v1 game whose policy node plays both robots (following the weights signed by the keys in folder
    ``trusted``, if given); it starts once the policy node and the trainer read every robot's detections, so the
    trainer sees each episode from its start."""
    options = {"namespace": namespace} if namespace else {}
    # with a trainer's key, the test operator's too (its signed ~/accept_older_weights: test_trainer_faults)
    keys = {"trusted_weights_keys": [str(trusted)], **operator_params()} if trusted else {}
    policy = make_node(PolicyNode, parameter_overrides=_params(players_per_team=1, seed=seed + 1, **keys), **options)
    if trusted:     # the trainer's first weights act from the first period (they are fetched: a round trip or two)
        executor.add_node(policy)
        assert spin_until(executor, lambda: policy.weights_acting is not None, 60.0), policy.counts
    sim = make_node(SimNode, parameter_overrides=_params(players_per_team=1, seed=seed, falls_enabled=False,
                                                         publish_markers=False, wait_for_subscribers=2), **options)
    executor.add_node(sim)
    if not trusted:
        executor.add_node(policy)
    return sim, policy


def _trainer(make_node, executor, run_dir, **values):
    """A trainer node signing with the key pair in ``run_dir``'s parent folder ``keys`` (made if missing)."""
    private, _ = key_pair(Path(run_dir).parent / "keys")
    params = dict(players_per_team=1, sequence_length=4, batch_sequences=2, ppo_epochs=1, ppo_minibatches=1,
                  run_dir=str(run_dir), variant="pred", signing_key=str(private))
    params.update(values)
    trainer = make_node(TrainerNode, parameter_overrides=_params(**params))
    executor.add_node(trainer)
    return trainer


def test_the_trainer_rebuilds_what_the_policy_saw_and_chose(make_node, executor, tmp_path):
    """With learning rate 0 every version's weights are the first ones, so the learner's log-probability of each
    action it rebuilt from the wire must equal the one the policy node sent (up to float precision): observations,
    previous actions, recurrent state and action indices all mean what the policy saw."""
    trainer = _trainer(make_node, executor, tmp_path / "run", learning_rate=1e-7)
    for group in trainer.message_trainer.optimizer.param_groups:
        group["lr"] = 0.0
    sim, policy = _game(make_node, executor, trusted=tmp_path / "keys")
    assert spin_until(executor, lambda: trainer.message_trainer.progress.updates >= 3, 90.0), str(trainer.diagnostics())
    stats = trainer.message_trainer.last_stats
    assert stats["behaviour_log_prob_error"] < 1e-3, stats
    counts = trainer.assembler.counts
    assert counts["missing"] == 0 and counts["malformed"] == 0 and counts["late"] == 0, counts
    assert trainer.readers.games == {""} and {r for _, r in trainer.readers.robots} == {"team_a_0", "team_b_0"}


def test_weights_flow_back_and_the_policy_acts_with_new_versions(make_node, executor, tmp_path):
    trainer = _trainer(make_node, executor, tmp_path / "run", learning_rate=1e-3, max_policy_lag=2)
    sim, policy = _game(make_node, executor, trusted=tmp_path / "keys")
    assert spin_until(executor, lambda: trainer.message_trainer.progress.updates >= 4, 120.0), trainer.diagnostics()
    assert spin_until(executor, lambda: policy.policy_version >= 3, 30.0), (policy.policy_version, policy.counts)
    assert policy.weights_acting[0] == trainer.run_id and policy.counts["weights_refused"] == 0
    stats = trainer.message_trainer.last_stats
    assert stats["lag_versions_max"] <= 2
    values = trainer.diagnostics()
    assert int(values["updates"]) >= 4 and float(values["lag_versions_mean"]) <= 2
    trainer.destroy_node()                            # finishes the run directory
    run = tmp_path / "run"
    assert (run / "policy.safetensors").is_file() and (run / "checkpoints" / "latest").exists()
    summary = json.loads((run / "summary.json").read_text())
    assert summary["updates"] >= 4
    assert (run / "metrics.csv").read_text().count("\n") >= 4


def test_several_games_in_their_namespaces_feed_one_trainer(make_node, executor, tmp_path):
    trainer = _trainer(make_node, executor, tmp_path / "run", batch_sequences=4)
    _game(make_node, executor, "/game_1", seed=3, trusted=tmp_path / "keys")
    _game(make_node, executor, "/game_2", seed=7, trusted=tmp_path / "keys")
    assert spin_until(executor, lambda: trainer.message_trainer.progress.updates >= 2, 120.0), trainer.diagnostics()
    assert trainer.readers.games == {"/game_1", "/game_2"}
    assert {(g, r) for g, r in trainer.message_trainer.states} == {(g, r) for g in ("/game_1", "/game_2")
                                                           for r in ("team_a_0", "team_b_0")}
    assert trainer.assembler.counts["missing"] == 0


def test_parameters_are_checked_on_set_and_reach_the_learner(make_node, executor, tmp_path):
    from rcl_interfaces.srv import SetParameters
    trainer = _trainer(make_node, executor, tmp_path / "run", learning_team="a")
    client = trainer.create_client(SetParameters, "/trainer_node/set_parameters")
    assert client.wait_for_service(timeout_sec=5.0)

    def set_one(name, value):
        future = client.call_async(SetParameters.Request(parameters=[Parameter(name, value=value).to_parameter_msg()]))
        assert spin_until(executor, future.done, 10.0)
        return future.result().results[0]

    assert not set_one("learning_rate", -1.0).successful                   # below the declared range
    assert not set_one("max_policy_lag", 1.5).successful                   # wrong type
    assert not set_one("batch_sequences", 3).successful                    # read-only
    assert set_one("learning_rate", 5e-4).successful
    assert trainer.message_trainer.optimizer.param_groups[0]["lr"] == 5e-4
    assert set_one("max_policy_lag", 7).successful and trainer.message_trainer.max_policy_lag == 7
    assert set_one("entropy_coef", 0.05).successful and trainer.message_trainer.settings.entropy_coef == 0.05
    # learning_team "a": both robots are discovered, only team A's experience is learnt (the trainer reads team B's
    # detections not at all, so this game starts with one reader per robot)
    sim = make_node(SimNode, parameter_overrides=_params(players_per_team=1, seed=3, publish_markers=False))
    policy = make_node(PolicyNode, parameter_overrides=_params(players_per_team=1, seed=4,
                                                               trusted_weights_keys=[str(tmp_path / "keys")]))
    executor.add_node(sim)
    executor.add_node(policy)
    assert spin_until(executor, lambda: trainer.assembler.counts["sequences"] >= 2, 60.0), trainer.diagnostics()
    assert {robot for _, robot in trainer.readers.robots} == {"team_a_0", "team_b_0"}
    assert {robot for _, robot in trainer.assembler.streams} == {"team_a_0"}


def test_a_trainer_without_a_signing_key_refuses_to_start(make_node, tmp_path, monkeypatch):
    from rclpy.exceptions import ParameterException
    monkeypatch.setenv("DYNENV_KEYS_DIR", str(tmp_path / "no_keys"))
    with pytest.raises(ParameterException, match=r"no signing key: run `dynenv-keys generate .*no_keys`"):
        make_node(TrainerNode, parameter_overrides=_params(players_per_team=1, run_dir=str(tmp_path / "run")))
    assert not (tmp_path / "run").exists()                      # refused before anything was written
    private, _ = key_pair(tmp_path / "no_keys")
    private.chmod(0o640)
    with pytest.raises(ParameterException, match="has mode 0640"):
        make_node(TrainerNode, parameter_overrides=_params(players_per_team=1, run_dir=str(tmp_path / "run")))
    private.chmod(0o600)                                         # the default folder's trainer.key, no parameter
    trainer = make_node(TrainerNode, parameter_overrides=_params(players_per_team=1, run_dir=str(tmp_path / "run"),
                                                                 variant="baseline", feature_size=16))
    assert trainer.weights.held and trainer.weights_published == 1
