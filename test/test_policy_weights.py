"""What the policy node tells a trainer (Action's learning fields) and how it takes a trainer's signed weights
(an announcement on /trainer/weights_announcement, the bytes from /trainer/weights_blob or fetched from the service
the announcement names: swapped in between decisions, refused with a reason and the old weights kept playing,
delivered at once to a node that starts late). The attacks from another process are in test_weights_attacks.py."""
from __future__ import annotations

import array
import dataclasses
import hashlib
import json
import math
import time

import numpy as np
import pytest
import torch
from dynenv_msgs.srv import FetchWeights
from rclpy.parameter import Parameter

from dynenv_ros.agent.checkpoint import policy_bytes, save_policy
from dynenv_ros.agent.network import DynEnvAgent
from dynenv_ros.ros.qos import latched
from dynenv_ros.ros.weights_release import to_message
from dynenv_ros.security.keys import load_private_key
from dynenv_ros.security.weights_signing import sign
from dynenv_ros.security.weights_source import source_of
from ros_harness import spin_until
from weights_helpers import SignedTrainer, key_pair, network_metadata
from policy_node.policy_node import PolicyNode
from test_policy_node_faults import Feeder, _policy_node

# Logits of each action head (walk 5, turn 3, kick 3, head 2·3+1 discrete steps of 37.5°/3) and the critic's output,
# set as the heads' biases with zero weights, so the policy's distribution does not depend on what it sees.
LOGITS = {"walk_head": [0.5, -1.0, 2.0, 0.0, 0.3], "turn_head": [1.0, 0.0, -0.5], "kick_head": [-2.0, 0.4, 0.1],
          "head_head": [0.0, 0.2, -0.3, 1.1, 0.0, -1.0, 0.6]}
VALUE = 2.5
HEAD_STEP = math.radians(37.5) / 3


def _fixed_policy() -> DynEnvAgent:
    torch.manual_seed(11)
    agent = DynEnvAgent()
    with torch.no_grad():
        for name, logits in LOGITS.items():
            layer = getattr(agent, name)
            layer.weight.zero_()
            layer.bias.copy_(torch.tensor(logits))
        agent.critic[-1].weight.zero_()
        agent.critic[-1].bias.fill_(VALUE)
    return agent.eval()


def _log_softmax(logits: list[float], index: int) -> float:
    return logits[index] - math.log(sum(math.exp(v) for v in logits))


def test_actions_carry_the_behaviour_log_probability_value_and_version(make_node, executor, tmp_path):
    path = tmp_path / "fixed.safetensors"
    save_policy(_fixed_policy(), path, {"updates": 41})
    policy = _policy_node(make_node, executor, checkpoint=str(path))
    feeder = Feeder(make_node, executor)
    feeder.wait_for()
    for period in range(6):
        action = feeder.act(period)["team_a_0"]
        head_index = round(action.head_yaw_delta / HEAD_STEP) + 3
        expected = (_log_softmax(LOGITS["walk_head"], action.walk) + _log_softmax(LOGITS["turn_head"], action.turn)
                    + _log_softmax(LOGITS["kick_head"], action.kick)
                    + _log_softmax(LOGITS["head_head"], head_index))
        assert action.policy_version == 42                     # 1 + the 41 updates the file records
        assert action.log_prob == pytest.approx(expected, abs=1e-5)
        assert action.value == pytest.approx(VALUE, abs=1e-5)
    assert policy.policy_version == 42


def _following(make_node, executor, tmp_path, **params):
    """A trusted stand-in trainer and a policy node that trusts its key."""
    private, public = key_pair(tmp_path / "keys")
    source = SignedTrainer(make_node, executor, private)
    policy = _policy_node(make_node, executor, trusted_weights_keys=[str(public)], **params)
    return source, policy


def test_signed_weights_are_fetched_and_swapped_in_and_bad_ones_refused(make_node, executor, tmp_path):
    source, policy = _following(make_node, executor, tmp_path)
    feeder = Feeder(make_node, executor)
    feeder.wait_for()
    assert feeder.act(0)["team_a_0"].policy_version == 0           # untrained smoke-test weights: not learnt from
    agent = _fixed_policy()
    good = policy_bytes(agent, {"updates": 6})
    meta = network_metadata(agent)
    source.release(good, version=7, metadata_json=meta)
    assert spin_until(executor, lambda: policy.policy_version == 7, 20.0), policy.counts
    assert policy.checkpoint_sha256 == hashlib.sha256(good).hexdigest()
    # 0.87 MB: one chunk, from the blob topic or the fetch service, whichever came first
    assert policy.counts["weights_blob_chunks"] + policy.counts["weights_fetch_chunks"] >= 1, policy.counts
    assert source.weights.served_chunks <= 1 and source.weights.blob_samples == 1
    action = feeder.act(1)["team_a_0"]
    assert action.policy_version == 7 and action.value == pytest.approx(VALUE, abs=1e-5)

    wide = DynEnvAgent(head_max=math.radians(80.0))       # beyond the simulator's head bound
    bad = {"damaged": (good[:-10] + b"0123456789", meta, "load_failed", "cannot be read safely"),
           "not a policy": (b"\x00" * 64, meta, "load_failed", "cannot be read safely"),
           "another network": (policy_bytes(DynEnvAgent(feature_size=32)), meta, "load_failed", "not the one announced"),
           "head bound": (policy_bytes(wide), network_metadata(wide), "load_failed", "head_max"),
           "driving": (good, network_metadata(DynEnvAgent(scenario="driving")), "wrong_network",
                       "this node plays soccer"),
           "no network": (good, "{}", "wrong_network", "does not describe a network")}
    for number, (name, (data, metadata, reason, text)) in enumerate(bad.items()):
        refused = policy.counts[f"weights_refused_{reason}"]
        source.release(data, version=8 + number, metadata_json=metadata)
        assert spin_until(executor, lambda: policy.counts[f"weights_refused_{reason}"] == refused + 1, 20.0), name
        assert text in policy.weights_refusal, (name, policy.weights_refusal)
        assert policy.policy_version == 7
        assert feeder.act(2 + number)["team_a_0"].policy_version == 7       # still playing the old weights
    diagnostics = policy.diagnostics()
    assert diagnostics["weights_refused"] == str(len(bad)) and diagnostics["weights_refused_load_failed"] == "4"
    # bytes that are not the ones signed, from a server without a blob topic: fetched (three times), never loaded
    source.weights.blob = False
    source.release(good, version=20, metadata_json=meta)
    source.weights.held[("run", 20)] = policy_bytes(DynEnvAgent(), {"updates": 19})
    assert spin_until(executor, lambda: policy.counts["weights_refused_hash_mismatch"] == 3, 30.0), policy.counts
    assert policy.policy_version == 7 and policy.checkpoint_sha256 == hashlib.sha256(good).hexdigest()


def test_the_blob_topic_delivers_without_the_fetch_service_and_the_service_without_the_blob(make_node, executor,
                                                                                           tmp_path):
    """Issue 43: the two routes of a release, each alone. With the trainer's node out of the executor its fetch
    service never answers, and the release comes by the blob topic (its writer is served by DDS, not the executor);
    a trainer that publishes no blob (its signed source names none) is fetched from its service."""
    private, public = key_pair(tmp_path / "keys")
    blob_only = SignedTrainer(make_node, executor, private)
    policy = _policy_node(make_node, executor, trusted_weights_keys=[str(public)])
    executor.remove_node(blob_only.node)
    agent = _fixed_policy()
    blob_only.release(policy_bytes(agent, {"updates": 1}), version=2, metadata_json=network_metadata(agent))
    assert spin_until(executor, lambda: policy.policy_version == 2, 20.0), policy.counts
    values = policy.weights.diagnostics()
    assert values["weights_route"] == "blob" and values["weights_loaded_via_blob"] == "1", values
    assert values["weights_source"] == "/fake_trainer" and blob_only.weights.served_chunks == 0
    fetch_only = SignedTrainer(make_node, executor, private, name="fetch_trainer", blob=False)
    data = policy_bytes(agent, {"updates": 2})
    fetch_only.release(data, version=3, metadata_json=network_metadata(agent))
    assert spin_until(executor, lambda: policy.policy_version == 3, 20.0), policy.counts
    values = policy.weights.diagnostics()
    assert values["weights_route"] == "fetch" and values["weights_loaded_via_fetch"] == "1", values
    assert values["weights_source"] == "/fetch_trainer" and fetch_only.weights.served_chunks == 1
    assert policy.checkpoint_sha256 == hashlib.sha256(data).hexdigest()
    assert values["weights_blob_chunks"] == "1" and values["weights_fetch_chunks"] == "1"


def test_a_silent_fetch_service_ends_an_attempt_as_fetch_failed_and_the_release_is_taken_when_it_answers(
        make_node, executor, tmp_path):
    """docs/ros_graph.md, "Who may change the weights": a chunk request unanswered for 2 s is sent again; after 5
    retries in vain (6 requests) the attempt ends as ``fetch_failed``; the release stays wanted, is asked again
    after the backoff, and is taken once the service answers (here the trainer's node out of the executor: a
    server on the graph that answers nothing, and no blob)."""
    from dynenv_ros.ros.weights_follower import MAX_TRIES
    private, public = key_pair(tmp_path / "keys")
    trainer = SignedTrainer(make_node, executor, private, blob=False)
    policy = _policy_node(make_node, executor, trusted_weights_keys=[str(public)])
    executor.remove_node(trainer.node)
    agent = _fixed_policy()
    data = policy_bytes(agent, {"updates": 1})
    trainer.release(data, version=2, metadata_json=network_metadata(agent))
    assert spin_until(executor, lambda: policy.counts["weights_refused_fetch_failed"] >= 1, 60.0), policy.counts
    assert policy.counts["weights_fetch_retries"] == MAX_TRIES + 1 == 6, policy.counts
    assert policy.policy_version == 0 and "failed 6 times" in policy.weights_refusal, policy.weights_refusal
    executor.add_node(trainer.node)
    assert spin_until(executor, lambda: policy.policy_version == 2, 60.0), policy.counts
    assert policy.counts["weights_fetch_restarts"] >= 1 and policy.checkpoint_sha256 == hashlib.sha256(data).hexdigest()
    assert policy.weights.diagnostics()["weights_route"] == "fetch"


def test_a_release_whose_blob_never_comes_is_fetched_from_the_service(make_node, executor, tmp_path):
    """docs/ros_graph.md: the fetch service is asked after 2 s without blob progress. The trainer's source names
    its blob topic, but its blob writer is gone before the node takes the announcement (nothing holds the bytes
    there): the release comes by the fetch service alone."""
    private, public = key_pair(tmp_path / "keys")
    trainer = SignedTrainer(make_node, executor, private)
    policy = _policy_node(make_node, executor, trusted_weights_keys=[str(public)])
    agent = _fixed_policy()
    data = policy_bytes(agent, {"updates": 1})
    announcement = trainer.release(data, version=2, metadata_json=network_metadata(agent))
    trainer.node.destroy_publisher(trainer.weights.blob_publisher)
    assert source_of(announcement).blob_topic == "/trainer/weights_blob"      # a blob release
    assert spin_until(executor, lambda: policy.policy_version == 2, 30.0), policy.counts
    values = policy.weights.diagnostics()
    assert values["weights_route"] == "fetch" and values["weights_loaded_via_fetch"] == "1", values
    assert values["weights_blob_chunks"] == "0" and trainer.weights.served_chunks == 1, values
    assert policy.checkpoint_sha256 == hashlib.sha256(data).hexdigest()


def test_a_blob_release_pushed_out_of_the_reader_comes_again_after_a_resubscription(make_node, executor, tmp_path):
    """docs/ros_graph.md: without blob progress for 5 s the node subscribes again and the trainer's writer hands the
    release out again. While the node's executor is busy, 40 junk samples from another writer push the genuine one
    out of its reader (4 deep for a file of one chunk), and the junk writer is gone before the node spins again; the
    trainer's fetch service never answers (its node out of the executor), so only the resubscription can bring the
    release."""
    private, public = key_pair(tmp_path / "keys")
    trainer = SignedTrainer(make_node, executor, private)
    policy = _policy_node(make_node, executor, trusted_weights_keys=[str(public)])
    executor.remove_node(trainer.node)
    junk_node = make_node("junk_writer")
    junk = junk_node.create_publisher(FetchWeights.Response, "/trainer/weights_blob", latched(64))
    agent = _fixed_policy()
    data = policy_bytes(agent, {"updates": 1})
    trainer.release(data, version=2, metadata_json=network_metadata(agent))
    assert spin_until(executor, lambda: policy.weights.wanted is not None, 20.0), policy.counts   # reader made
    deadline = time.monotonic() + 10.0        # nothing spins from here: both writers match the new reader
    while (junk.get_subscription_count() < 1 or trainer.weights.blob_publisher.get_subscription_count() < 1) \
            and time.monotonic() < deadline:
        time.sleep(0.05)
    time.sleep(1.0)                           # the genuine sample lands in the reader first …
    rng = np.random.default_rng(3)
    for _ in range(40):                       # … then the junk pushes it out
        junk.publish(FetchWeights.Response(success=True, data=array.array("B", rng.bytes(4096))))
    time.sleep(1.0)
    junk_node.destroy_publisher(junk)         # gone: a new reader gets the trainer's samples alone
    assert spin_until(executor, lambda: policy.policy_version == 2, 30.0), policy.weights.diagnostics()
    values = policy.weights.diagnostics()
    assert int(values["weights_blob_resubscribes"]) >= 1 and int(values["weights_blob_refused"]) >= 1, values
    assert values["weights_route"] == "blob" and trainer.weights.served_chunks == 0, values
    assert policy.checkpoint_sha256 == hashlib.sha256(data).hexdigest()


def test_a_fetch_service_gone_ends_an_attempt_after_the_stall_bound(make_node, executor, tmp_path):
    """docs/ros_graph.md: 30 s without progress ends a fetch attempt as ``fetch_failed`` (here the node's bound set
    to 3 s). The trainer's fetch service is gone after the announcement and no blob is published: no chunk request
    can go out (none is retried), the stall ends the attempt, and the release is taken once the service is back."""
    from dynenv_ros.ros.weights_follower import WeightsFollower
    assert WeightsFollower.stall_s == 30.0                               # the documented default
    private, public = key_pair(tmp_path / "keys")
    trainer = SignedTrainer(make_node, executor, private, blob=False)
    policy = _policy_node(make_node, executor, trusted_weights_keys=[str(public)])
    policy.weights.stall_s = 3.0
    agent = _fixed_policy()
    data = policy_bytes(agent, {"updates": 1})
    trainer.release(data, version=2, metadata_json=network_metadata(agent))
    service_name = trainer.weights.service.service_name
    trainer.node.destroy_service(trainer.weights.service)
    assert spin_until(executor, lambda: policy.counts["weights_refused_fetch_failed"] >= 1, 30.0), policy.counts
    assert f"no chunk for 3 s (service {service_name} gone or silent)" in policy.weights_refusal, policy.weights_refusal
    assert policy.counts["weights_fetch_retries"] == 0 and policy.policy_version == 0, policy.counts
    trainer.weights.service = trainer.node.create_service(FetchWeights, service_name, trainer.weights._on_fetch)
    assert spin_until(executor, lambda: policy.policy_version == 2, 30.0), policy.counts
    assert policy.counts["weights_fetch_restarts"] >= 1 and policy.checkpoint_sha256 == hashlib.sha256(data).hexdigest()


def test_a_newer_release_waits_for_the_running_attempt_and_starts_when_it_ends(make_node, executor, tmp_path):
    """docs/ros_graph.md: a newer release announced while a service attempt runs waits, the newest only, and starts
    when the attempt ends. Version 2 is being fetched from a trainer whose service does not answer yet (its node out
    of the executor), versions 3 and 4 are announced meanwhile: 4 waits in 3's place; once the service answers, 2
    is taken, then 4 — 3 never."""
    private, public = key_pair(tmp_path / "keys")
    trainer = SignedTrainer(make_node, executor, private, blob=False)
    policy = _policy_node(make_node, executor, trusted_weights_keys=[str(public)])
    executor.remove_node(trainer.node)
    agent = _fixed_policy()
    files = {v: policy_bytes(agent, {"updates": v}) for v in (2, 3, 4)}
    trainer.release(files[2], version=2, metadata_json=network_metadata(agent))
    assert spin_until(executor, lambda: policy.weights.wanted is not None and policy.weights.wanted.running,
                      20.0), policy.counts
    for version in (3, 4):
        trainer.release(files[version], version=version, metadata_json=network_metadata(agent))
        assert spin_until(executor, lambda: policy.weights.pending is not None
                          and policy.weights.pending.version == version, 10.0), policy.counts
        assert policy.weights.wanted.announcement.version == 2 and policy.weights.wanted.running
    trainer.weights.held[("run", 2)] = files[2]          # the trainer holds 2 releases: keep 2 servable too
    executor.add_node(trainer.node)
    assert spin_until(executor, lambda: policy.policy_version == 4, 30.0), policy.counts
    assert policy.counts["weights_loaded"] == 2 and policy.counts["weights_refused"] == 0, policy.counts
    assert policy.checkpoint_sha256 == hashlib.sha256(files[4]).hexdigest()


def test_a_file_of_several_chunks_reaches_a_busy_node_whole_by_the_blob_topic(make_node, executor, tmp_path):
    """A 4.4 MB policy file: the manifest and 5 chunks on the blob topic, handed out in one burst when the node
    subscribes. The node's executor is busy for 3 s meanwhile (nothing spins); its reader, as deep as the release
    has samples, keeps them all, so the file arrives whole by the blob alone (the trainer's service never answers)."""
    private, public = key_pair(tmp_path / "keys")
    trainer = SignedTrainer(make_node, executor, private)
    policy = _policy_node(make_node, executor, trusted_weights_keys=[str(public)])
    executor.remove_node(trainer.node)
    agent = DynEnvAgent(feature_size=160)
    data = policy_bytes(agent, {"updates": 4})
    assert 4 * 2**20 < len(data) < 5 * 2**20                            # 5 chunks of at most 1 MiB
    trainer.release(data, version=5, metadata_json=network_metadata(agent))
    assert spin_until(executor, lambda: policy.weights.wanted is not None, 20.0), policy.counts
    time.sleep(3.0)                                                     # a busy node: nothing taken meanwhile
    assert spin_until(executor, lambda: policy.policy_version == 5, 30.0), policy.weights.diagnostics()
    values = policy.weights.diagnostics()
    assert values["weights_route"] == "blob" and values["weights_blob_chunks"] == "6", values    # manifest + 5
    assert values["weights_blob_refused_unverifiable"] == "0" and trainer.weights.served_chunks == 0, values
    assert policy.checkpoint_sha256 == hashlib.sha256(data).hexdigest()


def test_an_announcement_without_a_signed_source_is_refused_before_any_fetch(make_node, executor, tmp_path):
    """A trainer from before issue 43 signs no source: refused as ``no_source`` (docs/decisions.md), even under the
    trusted key; a source whose fetch service does not carry the signing key's id, ``bad_source``."""
    private, public = key_pair(tmp_path / "keys")
    trainer = SignedTrainer(make_node, executor, private)
    policy = _policy_node(make_node, executor, trusted_weights_keys=[str(public)])
    agent = _fixed_policy()
    data, meta = policy_bytes(agent), network_metadata(agent)
    current = trainer.release(data, version=1, metadata_json=meta)
    assert spin_until(executor, lambda: policy.policy_version == 1, 20.0), policy.counts
    key = load_private_key(private)
    sourced = json.loads(current.metadata_json)
    renamed = {**sourced, "source": {**sourced["source"], "fetch_service": "/trainer/fetch_weights"}}
    for version, metadata, reason, text in ((2, meta, "no_source", "names no source"),
                                            (3, json.dumps(renamed), "bad_source", "does not carry the signing key")):
        trainer.weights.publisher.publish(to_message(sign(dataclasses.replace(
            current, version=version, metadata_json=metadata), key)))
        assert spin_until(executor, lambda: policy.counts[f"weights_refused_{reason}"] == 1, 10.0), policy.counts
        assert text in policy.diagnostics()["weights_refusal"]
    assert policy.policy_version == 1 and trainer.weights.served_chunks == 0


def test_a_policy_node_that_starts_late_gets_the_latest_weights_at_once(make_node, executor, tmp_path):
    private, public = key_pair(tmp_path / "keys")
    source = SignedTrainer(make_node, executor, private, run_id="first")
    agent = _fixed_policy()
    data = policy_bytes(agent)
    source.release(data, version=3, metadata_json=network_metadata(agent))
    source.release(data, version=5, metadata_json=network_metadata(agent))   # depth 1: only this one is kept
    policy = _policy_node(make_node, executor, weights_run_id="first", trusted_weights_keys=[str(tmp_path / "keys")])
    assert spin_until(executor, lambda: policy.policy_version == 5, 20.0), policy.counts
    assert policy.counts["weights_loaded"] == 1 and policy.weights_acting == ("first", 5)
    other = policy.counts["weights_other_run"]
    source.weights.run_id = "second"
    source.release(policy_bytes(DynEnvAgent()), version=9, metadata_json=network_metadata(agent))   # ignored
    assert spin_until(executor, lambda: policy.counts["weights_other_run"] == other + 1, 10.0)
    assert policy.policy_version == 5


def test_without_a_trusted_key_a_trainers_weights_are_refused(make_node, executor, tmp_path):
    private, _ = key_pair(tmp_path / "keys")
    source = SignedTrainer(make_node, executor, private)
    agent = _fixed_policy()
    source.release(policy_bytes(agent), version=4, metadata_json=network_metadata(agent))
    policy = _policy_node(make_node, executor)
    assert spin_until(executor, lambda: policy.counts["weights_refused_untrusted_key"] >= 1, 10.0), policy.counts
    assert policy.policy_version == 0 and source.weights.served_chunks == 0
    assert "not trusted" in policy.weights_refusal


def test_a_node_with_weights_topic_empty_never_follows_a_trainer(make_node, executor, tmp_path):
    private, public = key_pair(tmp_path / "keys")
    source = SignedTrainer(make_node, executor, private)
    agent = _fixed_policy()
    source.release(policy_bytes(agent), version=4, metadata_json=network_metadata(agent))
    policy = _policy_node(make_node, executor, weights_topic="", trusted_weights_keys=[str(public)])
    assert policy.weights is None
    assert not spin_until(executor, lambda: policy.policy_version != 0, 1.0)


def test_bad_key_parameters_stop_the_node_with_one_line(make_node, tmp_path):
    from rclpy.exceptions import ParameterException
    with pytest.raises(ParameterException, match="does not exist"):
        make_node(PolicyNode, parameter_overrides=[Parameter("trusted_weights_keys", value=[str(tmp_path / "x.pub")])])
    (tmp_path / "state.json").write_text("[")
    with pytest.raises(ParameterException, match="cannot be read"):
        make_node(PolicyNode, parameter_overrides=[Parameter("weights_state_file", value=str(tmp_path / "state.json"))])
