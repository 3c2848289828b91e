"""Issue 27 item 2 on the ROS graph, as the attacker: a second process without team A's secret publishes forged
actions (no MAC, a random MAC, team B's secret), replays of team A's genuine actions, early actions with plausible
learning fields and forged feedback into a game (and a trainer) running with secrets. The simulator runs only the
genuine policy's actions and names them in its signed feedback; every refusal is counted by reason and logged once
per diagnostics period; the trainer learns on from the genuine messages only, every metric finite."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
import torch
from dynenv_msgs.msg import Action, DetectionArray, StepFeedback
from rcl_interfaces.msg import Log
from rclpy.exceptions import ParameterException
from rclpy.parameter import Parameter

from dynenv_ros.agent.checkpoint import load_policy
from dynenv_ros.nodes.sim_node import SimNode
from dynenv_ros.nodes.trainer_node import TrainerNode
from dynenv_ros.ros.qos import action_stream, sim_stream
from dynenv_ros.security.action_auth import (action_digest, check_action, check_feedback, load_game_secrets,
                                             write_game_secrets)
from dynenv_ros.soccer.config import robot_names
from policy_node.policy_node import PolicyNode
from policy_node.scripted_policy import ScriptedPolicyNode
from ros_harness import ATTACKER_OUTLIVES_THE_TEST_S, spin_until

ATTACKER = Path(__file__).with_name("action_attacker.py")
FORGED_LOG_PROB, FORGED_REWARD = -0.5, 0.5          # action_attacker.py's plausible values
REFUSED_LOG = "refused since the last report"


def _params(**values):
    return [Parameter(k, value=v) for k, v in values.items()]


def _secrets(tmp_path: Path) -> Path:
    return write_game_secrets(tmp_path / "secrets", robot_names(1))


def _attacker(secrets: Path, seconds: float) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, str(ATTACKER), "team_a_0", str(seconds), str(secrets)],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)


class _Watcher:
    """What a bystander on the domain sees on team_a_0's topics, and the simulator's log lines (/rosout)."""

    def __init__(self, make_node, executor) -> None:
        self.actions: list[Action] = []
        self.feedback: list[StepFeedback] = []
        self.refusal_lines: list[str] = []
        node = make_node("watcher")
        deep = action_stream()
        deep.depth = 5000                    # the attacker floods the topic: keep everything for the checks
        node.create_subscription(Action, "/team_a_0/action", self.actions.append, deep)
        node.create_subscription(StepFeedback, "/team_a_0/feedback", self.feedback.append, sim_stream())
        node.create_subscription(Log, "/rosout", self._on_log, 1000)
        executor.add_node(node)

    def drain(self, executor, quiet_s: float = 1.0) -> None:
        """Spin until nothing new arrived for ``quiet_s`` (a flooded topic's reader lags behind the others)."""
        while True:
            before = len(self.actions) + len(self.feedback)
            spin_until(executor, lambda: False, quiet_s)
            if len(self.actions) + len(self.feedback) == before:
                return

    def _on_log(self, msg: Log) -> None:
        if REFUSED_LOG in msg.msg:
            self.refusal_lines.append(f"{msg.name}: {msg.msg}")


def test_the_simulator_runs_only_the_genuine_teams_actions(make_node, executor, tmp_path):
    secrets = _secrets(tmp_path)
    keys = load_game_secrets(secrets, robot_names(1), simulator=True)
    watcher = _Watcher(make_node, executor)
    sim = make_node(SimNode, parameter_overrides=_params(
        players_per_team=1, seed=3, falls_enabled=False, publish_markers=False, wait_for_subscribers=1,
        wait_for_ground_truth_subscribers=1, secrets_dir=str(secrets), diagnostics_period=1.0))
    policy = make_node(PolicyNode, parameter_overrides=_params(players_per_team=1, team="a", seed=4,
                                                               secrets_dir=str(secrets), weights_topic=""))
    keeper = make_node(ScriptedPolicyNode, parameter_overrides=_params(robot="team_b_0", policy="keeper",
                                                                       secrets_dir=str(secrets)))
    for node in (sim, policy, keeper):
        executor.add_node(node)
    attacker = _attacker(secrets, ATTACKER_OUTLIVES_THE_TEST_S)
    counts = sim.session.counts
    try:
        assert spin_until(executor, lambda: counts["rejected_mac_missing"] >= 10 and counts["rejected_mac_invalid"]
                          >= 30 and counts["rejected_replayed"] >= 5 and sim.periods_run >= 20, 300.0), \
            (dict(counts), sim.periods_run, sim.diagnostics())
        periods = sim.periods_run
        assert spin_until(executor, lambda: sim.periods_run >= periods + 5, 90.0)     # the game goes on
        spin_until(executor, lambda: False, 1.5)      # the last diagnostics period's log line
    finally:
        attacker.kill()
        output = attacker.communicate(timeout=10)[0]
    for node in (sim, policy, keeper):                # the game stops; the watcher reads what is still queued
        executor.remove_node(node)
    watcher.drain(executor)
    diagnostics = sim.diagnostics()
    assert diagnostics["action_authentication"] == "on"
    for reason in ("mac_missing", "mac_invalid", "replayed"):
        assert int(diagnostics[f"rejected_{reason}"]) > 0, diagnostics
    # every period ran each robot's genuine action: accepted twice per period, never the attacker's
    assert counts["missing"] == 0 and counts["accepted"] >= 2 * sim.periods_run, diagnostics
    genuine = {action_digest(a, "/team_a_0/action") for a in watcher.actions
               if check_action(a, "/team_a_0/action", keys.for_agent("team_a_0")) == ""}
    assert genuine and all(a.log_prob != FORGED_LOG_PROB for a in watcher.actions if len(a.mac) and
                           check_action(a, "/team_a_0/action", keys.for_agent("team_a_0")) == "")
    signed = [f for f in watcher.feedback if check_feedback(f, "/team_a_0/feedback", keys.simulator) == ""]
    forged = [f for f in watcher.feedback if check_feedback(f, "/team_a_0/feedback", keys.simulator) != ""]
    run = [f for f in signed if f.motion_period > 0]
    assert len(run) >= 20 and forged, (len(signed), len(forged))
    unnamed = [(f.episode_id, f.motion_period) for f in run if bytes(f.action_digest) not in genuine]
    assert not unnamed, unnamed                                         # the simulator names the genuine action
    assert all(f.reward_primary != FORGED_REWARD for f in signed)
    # refusals summarised in the log, one line per diagnostics period at most — never one per refusal
    refused = sum(int(diagnostics[f"rejected_{r}"]) for r in ("mac_missing", "mac_invalid", "replayed"))
    lines = [line for line in watcher.refusal_lines if line.startswith("sim_node")]
    assert lines and len(lines) < refused / 5, (len(lines), refused, output)
    assert any("mac_invalid" in line for line in lines), lines[-3:]


def test_a_genuine_action_replayed_onto_a_team_mates_topic_never_runs(make_node, executor, tmp_path):
    """docs/ros_graph.md, "What it protects": the attacker, a second process with no secret, replays each of
    team_a_0's genuine actions onto team_a_1's topic as soon as it sees it, unchanged and with robot_id altered to
    team_a_1's. The action gate checks the robot_id against the topic first: the unchanged one is ``unknown_robot``;
    the altered one fits the topic but not its MAC (which covers topic and robot_id): ``mac_invalid``. None runs."""
    secrets = write_game_secrets(tmp_path / "secrets", robot_names(2))
    keys = load_game_secrets(secrets, robot_names(2), simulator=True)
    mate_topic = "/team_a_1/action"
    actions: list[Action] = []
    feedback: list[StepFeedback] = []
    bystander = make_node("bystander")
    deep = action_stream()
    deep.depth = 5000
    bystander.create_subscription(Action, mate_topic, actions.append, deep)
    bystander.create_subscription(StepFeedback, "/team_a_1/feedback", feedback.append, sim_stream())
    for robot in ("team_b_0", "team_b_1"):            # team B stands (not controlled): its frames have a reader
        bystander.create_subscription(DetectionArray, f"/{robot}/detections", lambda _: None, sim_stream())
    sim = make_node(SimNode, parameter_overrides=_params(
        players_per_team=2, seed=3, falls_enabled=False, publish_markers=False, wait_for_subscribers=1,
        wait_for_ground_truth_subscribers=0, controlled_robots=["team_a_0", "team_a_1"],
        secrets_dir=str(secrets)))
    policy = make_node(PolicyNode, parameter_overrides=_params(players_per_team=2, team="a", seed=4,
                                                               secrets_dir=str(secrets), weights_topic=""))
    for node in (bystander, sim, policy):
        executor.add_node(node)
    mate_id = robot_names(2).index("team_a_1")
    attacker = subprocess.Popen([sys.executable, str(ATTACKER), "team_a_0", str(ATTACKER_OUTLIVES_THE_TEST_S),
                                 str(secrets), "teammate",
                                 "team_a_1", str(mate_id)], stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                text=True)
    counts = sim.session.counts
    try:
        assert spin_until(executor, lambda: counts["rejected_unknown_robot"] >= 10
                          and counts["rejected_mac_invalid"] >= 10 and sim.periods_run >= 20, 300.0), \
            (dict(counts), sim.periods_run, sim.diagnostics())
    finally:
        attacker.kill()
        output = attacker.communicate(timeout=10)[0]
    executor.remove_node(sim)
    executor.remove_node(policy)
    spin_until(executor, lambda: False, 1.0)          # what is still queued for the bystander
    diagnostics = sim.diagnostics()
    # each refusal as the code gives it, and nothing else refused: no replay reached the nonce check
    assert int(diagnostics["rejected_unknown_robot"]) >= 10 and int(diagnostics["rejected_mac_invalid"]) >= 10, \
        diagnostics
    assert diagnostics["rejected_mac_missing"] == "0" and diagnostics["rejected_replayed"] == "0", diagnostics
    # none ran: every period ran both team A robots' own actions, and team_a_1's signed feedback names only
    # actions that verify on its own topic under team A's secret (the attacker's replays verify on neither)
    assert counts["missing"] == 0 and counts["accepted"] >= 2 * sim.periods_run, diagnostics
    replays = [a for a in actions if a.robot_id != mate_id or
               check_action(a, mate_topic, keys.for_agent("team_a_1")) != ""]
    assert len(replays) >= 20, (len(replays), output)
    own = {action_digest(a, mate_topic) for a in actions if a.robot_id == mate_id and
           check_action(a, mate_topic, keys.for_agent("team_a_1")) == ""}
    ran = [f for f in feedback if check_feedback(f, "/team_a_1/feedback", keys.simulator) == ""
           and f.motion_period > 0]
    assert len(ran) >= 20 and all(bytes(f.action_digest) in own for f in ran), (len(ran), len(own))


def test_forged_and_replayed_messages_leave_learning_going_on_genuine_experience(make_node, executor, tmp_path):
    from weights_helpers import key_pair
    secrets = _secrets(tmp_path)
    private, public = key_pair(tmp_path / "keys")
    watcher = _Watcher(make_node, executor)
    trainer = make_node(TrainerNode, parameter_overrides=_params(
        players_per_team=1, sequence_length=4, batch_sequences=2, ppo_epochs=1, ppo_minibatches=1,
        variant="baseline", feature_size=16, run_dir=str(tmp_path / "run"), signing_key=str(private),
        secrets_dir=str(secrets)))
    learnt = []
    put = trainer.background.put
    trainer.background.put = lambda sequences: (learnt.extend(sequences), put(sequences))[1]
    sim = make_node(SimNode, parameter_overrides=_params(
        players_per_team=1, seed=5, falls_enabled=False, publish_markers=False, wait_for_subscribers=2,
        secrets_dir=str(secrets)))
    policy = make_node(PolicyNode, parameter_overrides=_params(players_per_team=1, seed=6, secrets_dir=str(secrets),
                                                               trusted_weights_keys=[str(public)]))
    for node in (trainer, sim, policy):
        executor.add_node(node)
    attacker = _attacker(secrets, ATTACKER_OUTLIVES_THE_TEST_S)
    counts = trainer.assembler.counts
    try:
        assert spin_until(executor, lambda: trainer.message_trainer.progress.updates >= 5 and counts["action_mac_invalid"] >= 20
                          and counts["action_mac_missing"] >= 5 and counts["feedback_mac_missing"] >= 5
                          and counts["feedback_mac_invalid"] >= 5, 300.0), (dict(counts), trainer.diagnostics())
        spin_until(executor, lambda: False, 1.5)
    finally:
        attacker.kill()
        output = attacker.communicate(timeout=10)[0]
    diagnostics = trainer.diagnostics()
    assert not trainer.background.error and diagnostics["action_authentication"] == "on", diagnostics
    assert int(sim.diagnostics()["rejected_mac_invalid"]) > 0 and sim.session.counts["missing"] == 0
    assert "mac_" in diagnostics["last_refused"], diagnostics
    # nothing the attacker sent was learnt: its plausible log-probability and rewards appear in no sequence
    assert learnt and all(FORGED_LOG_PROB not in s.log_probs.tolist() for s in learnt)
    assert all(FORGED_REWARD not in s.reward_terms[:, 0].tolist() for s in learnt)
    assert int(diagnostics.get("nonfinite_loss_skipped", 0)) == 0, diagnostics
    for name, tensor in trainer.message_trainer.agent.state_dict().items():
        assert bool(torch.isfinite(tensor).all()), name
    stats = [v for v in trainer.message_trainer.last_stats.values() if isinstance(v, float)]
    assert all(torch.isfinite(torch.tensor(stats))), trainer.message_trainer.last_stats
    lines = [line for line in watcher.refusal_lines if line.startswith("trainer_node")]
    assert lines and "action_mac_invalid" in " ".join(lines), (lines[-3:], output)
    trainer.destroy_node()                           # the policy file is loadable, so finite
    load_policy(tmp_path / "run" / "policy.safetensors")


@pytest.mark.parametrize("node_class, extra", [
    (SimNode, {"players_per_team": 1}), (PolicyNode, {"players_per_team": 1, "weights_topic": ""}),
    (ScriptedPolicyNode, {"robot": "team_b_0"})])
def test_a_missing_or_unsafe_secret_stops_a_node_with_one_line(make_node, tmp_path, node_class, extra):
    folder = tmp_path / "secrets"
    folder.mkdir()
    with pytest.raises(ParameterException, match=r"team_[ab]\.secret does not exist") as raised:
        make_node(node_class, parameter_overrides=_params(secrets_dir=str(folder), **extra))
    assert "\n" not in str(raised.value)
    write_game_secrets(folder, robot_names(1))
    (folder / "team_b.secret").chmod(0o644)
    with pytest.raises(ParameterException, match="has mode 0644"):
        make_node(node_class, parameter_overrides=_params(secrets_dir=str(folder), **extra))


@pytest.mark.parametrize("scenario", ["robocup", "driving"])
def test_every_policy_node_tags_what_it_sends(make_node, executor, tmp_path, scenario):
    """The perceiving policy (soccer) and the scripted driver (driving) act in a game that requires MACs."""
    from policy_node.perceiving_policy import PerceivingPolicyNode
    from policy_node.scripted_driver import ScriptedDriverNode
    if scenario == "driving":
        secrets = write_game_secrets(tmp_path / "secrets", ["car_0", "car_1"])
        sim = make_node(SimNode, parameter_overrides=_params(scenario="driving", n_cars=2, seed=1,
                                                             publish_markers=False, wait_for_subscribers=1,
                                                             wait_for_ground_truth_subscribers=1,
                                                             secrets_dir=str(secrets)))
        players = [make_node(ScriptedDriverNode, parameter_overrides=_params(n_cars=2, secrets_dir=str(secrets)))]
    else:
        secrets = _secrets(tmp_path)
        sim = make_node(SimNode, parameter_overrides=_params(players_per_team=1, seed=3, publish_markers=False,
                                                             secrets_dir=str(secrets)))
        players = [make_node(PolicyNode, parameter_overrides=_params(players_per_team=1, team="a", seed=4,
                                                                     secrets_dir=str(secrets), weights_topic="")),
                   make_node(PerceivingPolicyNode, parameter_overrides=_params(robot="team_b_0", players_per_team=1,
                                                                               secrets_dir=str(secrets)))]
    for node in (sim, *players):
        executor.add_node(node)
    assert spin_until(executor, lambda: sim.periods_run >= 10, 90.0), sim.diagnostics()
    diagnostics = sim.diagnostics()
    assert diagnostics["action_authentication"] == "on" and sim.session.counts["missing"] == 0, diagnostics
    assert all(diagnostics[f"rejected_{r}"] == "0" for r in ("mac_missing", "mac_invalid", "replayed")), diagnostics


def test_the_deployment_profile_starts_a_policy_node_that_tags(make_node, tmp_path):
    """config/deploy_policy_node.yaml, as docs/deploy.md runs it, with a robot's directory: its team's secret only."""
    import yaml

    from dynenv_ros.security.action_auth import write_team_secret
    repo = Path(__file__).resolve().parent.parent
    values = yaml.safe_load((repo / "config" / "deploy_policy_node.yaml").read_text())["/**"]["ros__parameters"]
    assert values["secrets_dir"] and values["runtime"] == "onnxruntime"
    write_team_secret(tmp_path / "robot" / "team_a.secret")
    values.update(secrets_dir=str(tmp_path / "robot"), players_per_team=2, team="a",
                  checkpoint=str(repo / "policy_node" / "pretrained" / "policy.onnx"))
    policy = make_node(PolicyNode, parameter_overrides=_params(**values))
    assert policy.tag_action.secrets is not None and set(policy.tag_action.secrets.teams) == {"team_a"}
    with pytest.raises(ParameterException, match="team_b.secret does not exist"):
        make_node(PolicyNode, parameter_overrides=_params(**{**values, "team": "b"}))
