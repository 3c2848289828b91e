"""The training graph under faults, launch-free: a trainer killed with SIGKILL leaves the policy nodes playing on
their last weights and a restarted one resumes from its last checkpoint; a killed simulator leaves the trainer
learning from the other games; hostile experience messages are dropped and counted."""
from __future__ import annotations

import math
import signal
import subprocess
import sys
import warnings

from dynenv_msgs.msg import Action, DetectionArray, StepFeedback
from dynenv_msgs.srv import AcceptOlderWeights

from dynenv_ros.learning.run import checkpoints
from dynenv_ros.nodes.trainer_node import TrainerNode
from dynenv_ros.ros.qos import action_stream, sim_stream
from policy_node.policy_node import PolicyNode
from operator_helpers import signed_call
from ros_harness import spin_until
from weights_helpers import key_pair
from test_trainer_node import _game, _params, _trainer

TRAINER = dict(players_per_team=1, sequence_length=4, batch_sequences=2, ppo_epochs=1, ppo_minibatches=1,
               variant="baseline", feature_size=16, checkpoint_every_minutes=0.01)


def _trainer_process(run_dir, resume=False) -> subprocess.Popen:
    """A trainer process signing with the key pair in run_dir's parent folder ``keys``."""
    private, _ = key_pair(run_dir.parent / "keys")
    args = [sys.executable, "-m", "dynenv_ros.nodes.trainer_node", "--ros-args"]
    for key, value in {**TRAINER, "run_dir": str(run_dir), "resume": resume, "signing_key": str(private)}.items():
        literal = ("true" if value else "false") if isinstance(value, bool) else value
        args += ["-p", f"{key}:={literal}"]
    return subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)


def test_a_killed_trainer_leaves_the_robots_playing_and_a_restarted_one_resumes(make_node, executor, tmp_path):
    run = tmp_path / "run"
    trainer = _trainer_process(run)
    try:
        sim, policy = _game(make_node, executor, trusted=tmp_path / "keys")
        assert spin_until(executor, lambda: policy.policy_version >= 4 and checkpoints.list_checkpoints(run),
                          120.0), (policy.policy_version, policy.counts)
        trainer.send_signal(signal.SIGKILL)
        trainer.wait(10)
        spin_until(executor, lambda: False, 1.0)         # weights already on their way when it died may land
        version, periods = policy.policy_version, sim.periods_run
        assert spin_until(executor, lambda: sim.periods_run >= periods + 20, 60.0)       # still playing
        assert policy.policy_version == version and policy.counts["fallback_actions"] == 0
        with warnings.catch_warnings():     # the kill may land while `latest` is replaced: the newest valid one
            warnings.simplefilter("ignore", checkpoints.CheckpointWarning)
            saved = checkpoints.read_checkpoint_meta(run)["updates"]
        loaded, rollbacks = policy.counts["weights_loaded"], policy.counts["weights_refused_rollback"]
        trainer = _trainer_process(run, resume=True)
        # the restarted trainer hands out its checkpoint's weights at once (version 1 + its updates): older than the
        # version acting, so refused as a rollback until the operator allows it once; then it learns on
        if saved + 1 <= version:
            assert spin_until(executor, lambda: policy.counts["weights_refused_rollback"] > rollbacks, 60.0)
            named = AcceptOlderWeights.Request(run_id=policy.weights_acting[0], version=saved + 1)
            assert "will be accepted once" in signed_call(policy, executor, AcceptOlderWeights,
                                                          "/policy_node/accept_older_weights", named).message
        assert spin_until(executor, lambda: policy.counts["weights_loaded"] > loaded, 60.0), policy.counts
        assert policy.weights_acting[1] >= saved + 1
        assert spin_until(executor, lambda: policy.policy_version > saved + 2, 120.0), policy.policy_version
    finally:
        trainer.kill()
        output = trainer.communicate(timeout=10)[0]
    assert f"version {saved + 1}" in output, output[-2000:]


def test_a_killed_simulator_leaves_the_trainer_learning_from_the_other_games(make_node, executor, tmp_path):
    trainer = _trainer(make_node, executor, tmp_path / "run", batch_sequences=2, variant="baseline", feature_size=16)
    _game(make_node, executor, "/game_2", seed=7, trusted=tmp_path / "keys")
    sim_1 = subprocess.Popen([sys.executable, "-m", "dynenv_ros.nodes.sim_node", "--ros-args", "-r", "__ns:=/game_1",
                              "-p", "players_per_team:=1", "-p", "wait_for_subscribers:=2", "-p",
                              "publish_markers:=false"], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    policy_1 = make_node(PolicyNode, parameter_overrides=_params(players_per_team=1, seed=9,
                                                                 trusted_weights_keys=[str(tmp_path / "keys")]),
                         namespace="/game_1")
    executor.add_node(policy_1)
    try:
        assert spin_until(executor, lambda: {s for s, _ in trainer.message_trainer.states} == {"/game_1", "/game_2"},
                          120.0), trainer.diagnostics()
        sim_1.send_signal(signal.SIGKILL)
        sim_1.wait(10)
        updates = trainer.message_trainer.progress.updates
        assert spin_until(executor, lambda: trainer.message_trainer.progress.updates >= updates + 4, 120.0), trainer.diagnostics()
        learnt = {stream: entry[0] for stream, entry in trainer.message_trainer.states.items()}   # game 1's last ones learnt
        assert spin_until(executor, lambda: trainer.message_trainer.progress.updates >= updates + 8, 120.0), trainer.diagnostics()
        assert not trainer.background.error
        after = {stream: entry[0] for stream, entry in trainer.message_trainer.states.items()}
        # game 2 goes on (a stream of it not yet learnt at the first look counts from nothing)
        assert all(after[s] > learnt.get(s, -1) for s in after if s[0] == "/game_2")
        assert all(after[s] == learnt[s] for s in after if s[0] == "/game_1")          # game 1 is gone
    finally:
        sim_1.kill()


def test_hostile_experience_is_dropped_and_counted(make_node, executor, tmp_path):
    trainer = _trainer(make_node, executor, tmp_path / "run", variant="baseline", feature_size=16)
    hostile = make_node("hostile")
    detections = hostile.create_publisher(DetectionArray, "/team_a_0/detections", sim_stream())
    actions = hostile.create_publisher(Action, "/team_a_0/action", action_stream())     # posing as a policy
    feedback = hostile.create_publisher(StepFeedback, "/team_a_0/feedback", sim_stream())
    executor.add_node(hostile)
    assert spin_until(executor, lambda: ("", "team_a_0") in trainer.readers.robots
                      and actions.get_subscription_count() >= 1 and feedback.get_subscription_count() >= 1, 20.0)
    bad = [(detections, DetectionArray(robot_id=0, episode_id=1, motion_period=0, frame_index=7, frames_per_period=5)),
           (detections, DetectionArray(robot_id=0, episode_id=1, motion_period=0, frame_index=0, frames_per_period=0)),
           (detections, DetectionArray(robot_id=3, episode_id=1, motion_period=0, frame_index=0, frames_per_period=5)),
           (actions, Action(robot_id=0, episode_id=1, motion_period=1, walk=200, policy_version=1)),
           (actions, Action(robot_id=0, episode_id=1, motion_period=1, policy_version=1, log_prob=math.nan)),
           (actions, Action(robot_id=0, episode_id=1, motion_period=1, head_yaw_delta=math.inf)),
           (actions, Action(robot_id=0, episode_id=1, motion_period=0)),
           (feedback, StepFeedback(robot_id=0, episode_id=1, motion_period=1, reward_rule=math.nan)),
           (feedback, StepFeedback(robot_id=5, episode_id=1, motion_period=1))]
    for publisher, msg in bad:
        publisher.publish(msg)
    assert spin_until(executor, lambda: trainer.assembler.counts["malformed"] == len(bad), 10.0), \
        trainer.assembler.counts
    assert trainer.readers.received["errors"] == 0 and not trainer.background.error
    # and the graph still trains: a real game after the attack
    sim, policy = _game(make_node, executor, seed=5, trusted=tmp_path / "keys")
    assert spin_until(executor, lambda: trainer.message_trainer.progress.updates >= 2, 120.0), trainer.diagnostics()


def test_bad_settings_and_files_at_start_are_refused_with_the_reason(make_node, tmp_path):
    """A trainer that cannot start says which parameter and why (the node runner turns it into exit status 2)."""
    from rclpy.exceptions import ParameterException
    (tmp_path / "bad.safetensors").write_bytes(b"not a policy")
    (tmp_path / "empty").mkdir()
    cases = {"reward_weights": dict(reward_weights=[1.0, 2.0]),
             "initial_policy": dict(initial_policy=str(tmp_path / "bad.safetensors")),
             "resume": dict(resume=True, run_dir=str(tmp_path / "empty")),
             "batch_sequences": dict(batch_sequences=2, ppo_minibatches=4)}
    private, _ = key_pair(tmp_path / "keys")
    for key, values in cases.items():
        params = {**TRAINER, "run_dir": str(tmp_path / key), "signing_key": str(private), **values}
        try:
            make_node(TrainerNode, parameter_overrides=_params(**params))
        except ParameterException as error:
            assert str(error).startswith(f"{key}: ") and str(error).endswith(f"['{key}']"), (key, str(error))
        else:
            raise AssertionError(f"{key}: the trainer started")


def test_a_disk_too_small_is_refused_and_a_started_trainer_checkpoints_at_once(make_node, tmp_path, monkeypatch):
    """Issue 27 item 4 for the trainer node: a run directory on a disk without room for the run's checkpoints is
    refused at start naming run_dir, leaving no folder; a trainer that starts writes its first checkpoint before any
    experience arrives, so a SIGKILL a moment later still leaves a run that resume:=true continues."""
    from collections import namedtuple
    from rclpy.exceptions import ParameterException
    from dynenv_ros.core import writable
    private, _ = key_pair(tmp_path / "keys")
    usage = namedtuple("usage", "total used free")
    real = writable.shutil.disk_usage
    monkeypatch.setattr(writable.shutil, "disk_usage", lambda path: usage(10 * 2**20, 5 * 2**20, 5 * 2**20))
    small = tmp_path / "small" / "run"
    try:
        make_node(TrainerNode, parameter_overrides=_params(**{**TRAINER, "run_dir": str(small),
                                                               "signing_key": str(private)}))
    except ParameterException as error:
        assert str(error).startswith(f"run_dir {small}: needs about ") and "5.0 MB free" in str(error), str(error)
    else:
        raise AssertionError("the trainer started on a 5 MB disk")
    assert not (tmp_path / "small").exists()
    monkeypatch.setattr(writable.shutil, "disk_usage", real)
    run_dir = tmp_path / "run"
    make_node(TrainerNode, parameter_overrides=_params(**{**TRAINER, "run_dir": str(run_dir),
                                                          "signing_key": str(private)}))
    assert len(checkpoints.list_checkpoints(run_dir)) == 1
