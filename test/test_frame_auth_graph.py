"""Issue 43 item 4 on the ROS graph, as the attacker: a second process without frames.secret publishes forged
frames (untagged, with a random tag, with a tag under another team's secret) and replays genuine ones into a train
graph running with authenticated frames (simulator, policy node, trainer). Not one forged frame reaches the policy
node's decisions or the trainer's experience; every refusal is counted by reason. Without authenticated frames the
same attacker's frames do reach the policy node (the control)."""
from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

import pytest
from dynenv_msgs.msg import Action, DetectionArray, WorldState
from rclpy.exceptions import ParameterException
from rclpy.parameter import Parameter
from std_msgs.msg import UInt8MultiArray

from dynenv_ros.nodes.sim_node import SimNode
from dynenv_ros.nodes.trainer_node import TrainerNode
from dynenv_ros.ros.frame_tags import FrameReceiver, tag_message
from dynenv_ros.ros.qos import action_stream, sim_stream
from dynenv_ros.security.action_auth import load_secret, secret_path, write_game_secrets, write_team_secret
from dynenv_ros.security.frame_auth import FRAMES, FrameGate, detection_array_bytes, world_state_bytes
from dynenv_ros.soccer.config import robot_names
from policy_node.policy_node import PolicyNode
from policy_node.scripted_policy import ScriptedPolicyNode
from ros_harness import ATTACKER_OUTLIVES_THE_TEST_S, spin_until

ATTACKER = Path(__file__).with_name("frame_attacker.py")
MARK = 0.987654                                  # frame_attacker.py's forged height (genuine: z = 0)


def _params(**values):
    return [Parameter(k, value=v) for k, v in values.items()]


def _secrets(tmp_path: Path) -> Path:
    folder = write_game_secrets(tmp_path / "secrets", robot_names(1))
    write_team_secret(secret_path(folder, FRAMES))
    return folder


def _attacker(secrets: Path, seconds: float) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, str(ATTACKER), "team_a_0", str(seconds), str(secrets)],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)


def _forged(frames) -> int:
    return sum(any(d.position.z == MARK for d in f.detections) for f in frames)


def _record(target, name: str) -> list:
    """Every message passed to ``target.<name>`` from now on (what the node acts on or learns from)."""
    seen: list = []
    original = getattr(target, name)

    def recording(*args):
        seen.append(args[-1])
        return original(*args)
    setattr(target, name, recording)
    return seen


def test_no_forged_frame_reaches_the_policys_decisions_or_the_trainers_experience(make_node, executor, tmp_path):
    from weights_helpers import key_pair
    secrets = _secrets(tmp_path)
    private, public = key_pair(tmp_path / "keys")
    common = dict(secrets_dir=str(secrets), authenticated_frames=True)
    trainer = make_node(TrainerNode, parameter_overrides=_params(
        players_per_team=1, sequence_length=4, batch_sequences=2, ppo_epochs=1, ppo_minibatches=1,
        variant="baseline", feature_size=16, run_dir=str(tmp_path / "run"), signing_key=str(private), **common))
    learnt = _record(trainer.assembler, "add_frame")
    sim = make_node(SimNode, parameter_overrides=_params(
        players_per_team=1, seed=5, falls_enabled=False, publish_markers=False, wait_for_subscribers=2, **common))
    policy = make_node(PolicyNode, parameter_overrides=_params(players_per_team=1, seed=6,
                                                               trusted_weights_keys=[str(public)], **common))
    acted_on = _record(policy, "_store")
    # a bystander checks the simulator's world states against their tags
    world_gate = FrameGate(load_secret(secret_path(secrets, FRAMES)))
    world_states: list = []
    watcher = make_node("watcher")
    watcher.create_subscription(WorldState, "/world_state", lambda m: (world_states.append(m), world_gate.frame(
        m, world_state_bytes(m, "/world_state"), 0)), sim_stream())
    watcher.create_subscription(UInt8MultiArray, "/world_state_mac", lambda m: world_gate.tag(m.data, 0),
                                sim_stream())
    for node in (trainer, sim, policy, watcher):
        executor.add_node(node)
    attacker = _attacker(secrets, ATTACKER_OUTLIVES_THE_TEST_S)
    gate, learner_gate = policy.frame_gate.gate, trainer.readers.frame_gate.gate
    try:
        assert spin_until(executor, lambda: trainer.message_trainer.progress.updates >= 3 and gate.counts["frame_replayed"] >= 5
                          and gate.counts["frame_mac_missing"] >= 30 and learner_gate.counts["frame_mac_missing"]
                          >= 30 and sim.periods_run >= 20, 300.0), \
            (policy.diagnostics(), trainer.diagnostics())
    finally:
        attacker.kill()
        output = attacker.communicate(timeout=10)[0]
    # the attacker was there and sent its frames: every refusal counted by reason, in both nodes' diagnostics
    diagnostics, learner = policy.diagnostics(), trainer.diagnostics()
    assert diagnostics["frame_authentication"] == "on" and learner["frame_authentication"] == "on"
    assert int(diagnostics["frames_refused_frame_mac_missing"]) >= 30, diagnostics
    assert int(learner["frames_refused_frame_mac_missing"]) >= 30, learner
    assert int(diagnostics["frames_refused_frame_replayed"]) >= 5, diagnostics
    assert int(diagnostics["frames_verified"]) >= 100 and int(learner["frames_verified"]) >= 100
    # 0 forged frames reached the policy's decisions or the trainer's experience; the game and learning went on
    assert acted_on and learnt and _forged(acted_on) == 0 and _forged(learnt) == 0, output
    assert sim.session.counts["missing"] == 0 and int(policy.diagnostics()["decisions"]) >= 20
    assert not trainer.background.error and trainer.message_trainer.progress.updates >= 3
    # every world state the simulator published carries a tag that verifies (the bystander takes one message per
    # wake-up of the executor the nodes share, so it may still be catching up)
    assert spin_until(executor, lambda: len(world_states) >= 100, 60.0), len(world_states)
    assert world_gate.counts["frames_verified"] >= len(world_states) - 10
    assert world_gate.counts["frame_mac_missing"] == 0
    trainer.destroy_node()


def test_a_stepped_game_starts_only_once_its_tag_readers_have_matched(make_node, executor, tmp_path):
    """The train graph's stall under load (game 2 stuck at period 1, 4 frames verified): the simulator waited for
    the readers of its frames, not of their tags, and a tag published before its reader matched (discovery is
    asymmetric, and slow on a loaded machine) was lost, its frame refused, the period never complete, the stepped
    game stuck. Here a receiver reads the frames at once and the tags only later: the game must not start before
    the tag readers have matched, and then every frame of the first period verifies."""
    secrets = _secrets(tmp_path)
    sim = make_node(SimNode, parameter_overrides=_params(players_per_team=1, seed=5, falls_enabled=False,
                                                         publish_markers=False, wait_for_subscribers=1,
                                                         secrets_dir=str(secrets), authenticated_frames=True))
    receiver = make_node("late_tag_reader")
    gate = FrameGate(load_secret(secret_path(secrets, FRAMES)))
    frames: list = []
    for robot in robot_names(1):
        topic = f"/{robot}/detections"
        receiver.create_subscription(DetectionArray, topic, lambda m, t=topic: (frames.append(m), gate.frame(
            m, detection_array_bytes(m, t), 0)), sim_stream())
        receiver.create_publisher(Action, f"/{robot}/action", action_stream())     # someone acts for the robot
    for node in (sim, receiver):
        executor.add_node(node)
    assert not spin_until(executor, lambda: frames, 5.0), "the game started before its tags had a reader"
    for robot in robot_names(1):
        receiver.create_subscription(UInt8MultiArray, f"/{robot}/detections_mac", lambda m: gate.tag(m.data, 0),
                                     sim_stream())
    assert spin_until(executor, lambda: gate.counts["frames_verified"] >= 10, 30.0), (len(frames), gate.counts)
    assert {(f.motion_period, f.frame_index) for f in frames[:10]} == {(0, i) for i in range(5)}
    assert gate.counts["frame_mac_missing"] == 0 and gate.waiting == 0


def test_a_busy_receiver_takes_the_tags_already_queued_before_a_frame_can_expire(make_node, executor, tmp_path):
    """The other half of the stall under load: a receiver whose executor is busy longer than the gate's wait (2 s)
    while a frame's tag sits in its queue. Before, the next frame's arrival expired the first one (its tag
    unread), the period stayed incomplete and the stepped game stalled; now every queued tag is taken first."""
    secret = load_secret(secret_path(_secrets(tmp_path), FRAMES))
    node, sender = make_node("busy_receiver"), make_node("tagger")
    receiver = FrameReceiver(node, secret)
    released: list = []
    receiver.subscribe("/team_a_0/detections", sim_stream(), released.extend)
    tags = sender.create_publisher(UInt8MultiArray, "/team_a_0/detections_mac", sim_stream())
    for each in (node, sender):
        executor.add_node(each)
    assert spin_until(executor, lambda: tags.get_subscription_count() >= 1
                      and receiver.subscriptions[0].get_publisher_count() >= 1, 20.0)
    assert receiver.frame("first", b"first frame", "first") == []         # waits for its tag
    tags.publish(tag_message(secret, b"first frame"))
    time.sleep(3.0)                                    # busy: the executor runs nothing, the tag waits in the queue
    assert receiver.frame("second", b"second frame", "second") == ["first"]
    assert receiver.gate.counts["frame_mac_missing"] == 0 and receiver.gate.waiting == 1 and released == []


def test_without_authenticated_frames_the_attackers_frames_reach_the_policy(make_node, executor, tmp_path):
    """The control: the same attacker against a policy node that reads frames as they come (a real robot's
    default) gets its forged frames acted on."""
    secrets = _secrets(tmp_path)
    sim = make_node(SimNode, parameter_overrides=_params(players_per_team=1, seed=5, falls_enabled=False,
                                                         publish_markers=False, wait_for_subscribers=1))
    policy = make_node(PolicyNode, parameter_overrides=_params(players_per_team=1, team="a", seed=6,
                                                               weights_topic=""))
    keeper = make_node(ScriptedPolicyNode, parameter_overrides=_params(robot="team_b_0", policy="keeper"))
    acted_on = _record(policy, "_store")
    for node in (sim, policy, keeper):
        executor.add_node(node)
    attacker = _attacker(secrets, ATTACKER_OUTLIVES_THE_TEST_S)
    try:
        assert spin_until(executor, lambda: _forged(acted_on) >= 5, 150.0), policy.diagnostics()
    finally:
        attacker.kill()
        attacker.communicate(timeout=10)
    assert policy.diagnostics()["frame_authentication"] == "off" and policy.frame_gate is None


def test_authenticated_frames_need_frames_secret(make_node, tmp_path):
    folder = write_game_secrets(tmp_path / "secrets", robot_names(1))
    with pytest.raises(ParameterException, match="frames.secret does not exist"):
        make_node(SimNode, parameter_overrides=_params(players_per_team=1, secrets_dir=str(folder),
                                                       authenticated_frames=True))
    with pytest.raises(ParameterException, match="authenticated_frames needs secrets_dir"):
        make_node(PolicyNode, parameter_overrides=_params(players_per_team=1, weights_topic="",
                                                          authenticated_frames=True))


def test_the_ros_sports_interfaces_refuse_authenticated_frames(make_node, tmp_path):
    """docs/ros_graph.md, "Inventory": a team stack's soccer_vision_3d messages carry no tags, so a policy node on
    the ros-sports interfaces refuses authenticated_frames at start rather than run with frames nobody checks."""
    secrets = _secrets(tmp_path)
    shipped = Path(__file__).resolve().parents[1] / "policy_node" / "pretrained" / "policy.onnx"
    with pytest.raises(ParameterException, match="soccer_vision_3d messages carry no tags"):
        make_node(PolicyNode, parameter_overrides=_params(players_per_team=1, weights_topic="",
                                                          interfaces="ros_sports", checkpoint=str(shipped),
                                                          secrets_dir=str(secrets), authenticated_frames=True))
