"""Issue 43 item 5, as the attacker: a second process with no key and no secret calls the simulator's /sim/reset
and /sim/step and asks the simulator and the trainer to change their settable parameters. With runtime_controls
off (the deployment profile, the train graph) the services are not there, every change is refused with the reason,
and the game and the learning go on unchanged; with the local default they answer it (the control)."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import yaml
from rcl_interfaces.msg import Log
from rclpy.parameter import Parameter

from dynenv_ros.nodes.sim_node import SimNode
from dynenv_ros.nodes.trainer_node import TrainerNode
from dynenv_ros.ros.runtime_controls import REFUSED
from policy_node.scripted_policy import ScriptedPolicyNode
from ros_harness import spin_until

ATTACKER = Path(__file__).with_name("control_attacker.py")
ROOT = Path(__file__).resolve().parents[1]


def _params(**values):
    return [Parameter(k, value=v) for k, v in values.items()]


def _attack(executor, seconds: float) -> dict:
    """Run the attacker while the executor spins (so the nodes answer), and return what it saw."""
    attacker = subprocess.Popen([sys.executable, str(ATTACKER), str(seconds)], stdout=subprocess.PIPE,
                                stderr=subprocess.STDOUT, text=True)
    try:
        spin_until(executor, lambda: attacker.poll() is not None, seconds + 30.0)
    finally:
        attacker.kill()
        output = attacker.communicate(timeout=10)[0]
    return json.loads(output.strip().splitlines()[-1])


def _game(make_node, executor, **sim_values):
    sim = make_node(SimNode, parameter_overrides=_params(players_per_team=1, seed=5, falls_enabled=False,
                                                         publish_markers=False, wait_for_subscribers=0,
                                                         wait_for_ground_truth_subscribers=1, **sim_values))
    players = [make_node(ScriptedPolicyNode, parameter_overrides=_params(robot=r, policy="keeper"))
               for r in ("team_a_0", "team_b_0")]
    for node in (sim, *players):
        executor.add_node(node)
    return sim


def test_with_runtime_controls_off_no_call_changes_the_game_or_the_learning(make_node, executor, tmp_path):
    from weights_helpers import key_pair
    private, _ = key_pair(tmp_path / "keys")
    logs: list[str] = []
    watcher = make_node("watcher")
    watcher.create_subscription(Log, "/rosout", lambda m: logs.append(f"{m.name}: {m.msg}"), 100)
    executor.add_node(watcher)
    trainer = make_node(TrainerNode, parameter_overrides=_params(
        players_per_team=1, sequence_length=4, batch_sequences=2, ppo_epochs=1, ppo_minibatches=1,
        variant="baseline", feature_size=16, run_dir=str(tmp_path / "run"), signing_key=str(private),
        runtime_controls=False))
    executor.add_node(trainer)
    sim = _game(make_node, executor, runtime_controls=False, episode_seconds=3600.0)   # no episode ends by itself
    assert spin_until(executor, lambda: sim.periods_run >= 3, 60.0)
    episode, rate = sim.session.episode_id, trainer.message_trainer.optimizer.param_groups[0]["lr"]
    seen = _attack(executor, 8.0)
    assert seen["reset"] == "absent" and seen["step"] == "absent", seen
    assert seen["/sim_node"] == [{"name": n, "successful": False, "reason": REFUSED}
                                 for n in ("missing_action", "auto_reset", "use_sim_time")], seen
    assert seen["/trainer_node"] == [{"name": n, "successful": False, "reason": REFUSED}
                                     for n in ("learning_rate", "use_sim_time")], seen
    periods = sim.periods_run
    assert spin_until(executor, lambda: sim.periods_run >= periods + 3, 60.0)
    assert sim.session.episode_id == episode and sim.session.missing_action == "none" and sim.game.auto_reset
    assert trainer.message_trainer.optimizer.param_groups[0]["lr"] == rate == 1e-4
    assert not trainer.get_parameter("use_sim_time").value and not sim.get_parameter("use_sim_time").value
    assert sim.diagnostics()["runtime_controls"] == "off" and trainer.diagnostics()["runtime_controls"] == "off"
    spin_until(executor, lambda: False, 0.5)
    said = " ".join(logs)
    assert "sim_node: runtime_controls off: /sim/reset and /sim/step are not offered" in said, logs[:5]
    assert "trainer_node: runtime_controls off: learning_rate" in said, logs[:5]
    trainer.destroy_node()


def test_with_the_local_default_the_same_calls_change_the_game(make_node, executor):
    """The control: a local simulation (runtime_controls true) answers the attacker as it answers anyone."""
    sim = _game(make_node, executor)
    assert spin_until(executor, lambda: sim.periods_run >= 3, 60.0)
    episode = sim.session.episode_id
    seen = _attack(executor, 20.0)                 # up to 5 s to discover each service on a loaded machine
    assert seen["reset"] != "absent" and seen["reset"]["success"] and seen["step"]["success"], seen
    assert [r["successful"] for r in seen["/sim_node"]] == [True, True, True]
    assert sim.session.episode_id > episode and sim.session.missing_action == "hold" and not sim.game.auto_reset, \
        (episode, sim.session.episode_id, seen)


def test_a_robots_policy_node_with_runtime_controls_off_keeps_greedy_and_its_clock(make_node, executor):
    """The deployment profile's policy node: a remote greedy or use_sim_time change (which would move its decision
    deadline onto an attacker's /clock) is refused with the reason."""
    from policy_node.policy_node import PolicyNode
    node = make_node(PolicyNode, parameter_overrides=_params(players_per_team=1, team="a", greedy=True,
                                                             runtime_controls=False))
    executor.add_node(node)
    seen = _attack(executor, 8.0)
    assert seen["/policy_node"] == [{"name": n, "successful": False, "reason": REFUSED}
                                    for n in ("greedy", "use_sim_time")], seen
    assert node.get_parameter("greedy").value and not node.get_parameter("use_sim_time").value
    assert node.diagnostics()["runtime_controls"] == "off"


def test_the_deployment_profile_turns_the_runtime_controls_off():
    for name in ("sim_2v2_deploy.yaml", "deploy_policy_node.yaml"):
        profile = yaml.safe_load((ROOT / "config" / name).read_text())
        assert profile["/**"]["ros__parameters"]["runtime_controls"] is False, name
    from dynenv_ros.graph.train_graph import train_graph
    from types import SimpleNamespace
    import tempfile
    with tempfile.TemporaryDirectory() as folder:
        config = SimpleNamespace(players_per_team=1, seed=1, games=1, train_minutes=1.0, train_updates=0,
                                 perception="realistic", episode_seconds=10.0)
        launches = {n.name: n for n in train_graph(config, Path(folder))}
    for name in ("trainer", "sim_game_1", "policy_game_1"):
        assert launches[name].parameters["runtime_controls"] is False, name
    for name in ("trainer", "sim_game_1", "policy_game_1"):
        assert launches[name].parameters["authenticated_frames"] is True, name


def test_the_deployment_profiles_nodes_say_at_start_what_is_off(make_node, executor, tmp_path):
    """docs/deploy.md's routes table and config/*deploy*.yaml: a robot's policy node and the 2v2 simulator started
    from their deployment profiles say once at start which services and changes are off, and those services are
    not on the graph."""
    from dynenv_ros.security.action_auth import write_game_secrets
    from dynenv_ros.soccer.config import robot_names
    from policy_node.policy_node import PolicyNode
    logs: list[str] = []
    watcher = make_node("watcher")
    watcher.create_subscription(Log, "/rosout", lambda m: logs.append(f"{m.name}: {m.msg}"), 100)
    executor.add_node(watcher)
    secrets = write_game_secrets(tmp_path / "secrets", robot_names(2))

    def profile(name: str, **values) -> list[Parameter]:
        loaded = yaml.safe_load((ROOT / "config" / name).read_text())["/**"]["ros__parameters"]
        return _params(**{**loaded, "secrets_dir": str(secrets), **values})

    policy = make_node(PolicyNode, parameter_overrides=profile(
        "deploy_policy_node.yaml", players_per_team=2, team="a",
        checkpoint=str(ROOT / "policy_node" / "pretrained" / "policy.onnx")))
    sim = make_node(SimNode, parameter_overrides=profile("sim_2v2_deploy.yaml", publish_markers=False))
    for node in (policy, sim):
        executor.add_node(node)
    assert spin_until(executor, lambda: sum("runtime_controls off" in line for line in logs) >= 2, 10.0), logs
    said = " ".join(logs)
    assert "policy_node: no trusted_operator_keys: ~/load_policy and ~/accept_older_weights are off" in said, logs
    assert "policy_node: runtime_controls off: greedy and use_sim_time stay as started" in said, logs
    assert "policy_node: no trusted_weights_keys: weights announced by a trainer will be refused" in said, logs
    assert "sim_node: runtime_controls off: /sim/reset and /sim/step are not offered" in said, logs
    spin_until(executor, lambda: False, 1.0)
    services = {name for name, _ in watcher.get_service_names_and_types()}
    assert "/policy_node/get_parameters" in services and "/sim_node/get_parameters" in services, services
    assert not services & {"/policy_node/load_policy", "/policy_node/accept_older_weights", "/sim/reset",
                           "/sim/step"}, services
    assert policy.diagnostics()["operator_services"] == "off" and policy.diagnostics()["runtime_controls"] == "off"
    assert sim.diagnostics()["runtime_controls"] == "off"
