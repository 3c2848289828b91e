"""Bags record each topic's offered QoS and the player republishes with it (issue 28): a fresh recording's metadata
says /tf_static is transient local, and a TF listener that starts after bag_player published still gets the static
frames; bags without (or with wrong) QoS metadata keep playing with the documented default."""
from __future__ import annotations

import shutil
from pathlib import Path

import pytest
import yaml
from rclpy.duration import Duration
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, HistoryPolicy, LivelinessPolicy, QoSProfile, ReliabilityPolicy
from rclpy.serialization import serialize_message
from rosbags.interfaces import Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime

from dynenv_ros.bags.qos import DEFAULT_PLAYBACK_QOS, INFINITE, LATCHED_DEPTH_MAX, playback_qos
from dynenv_ros.bags.recovery import reindex
from dynenv_ros.bags.typestore import dynenv_typestore
from dynenv_ros.bags.writer import BagWriter
from dynenv_ros.ros import topics
from dynenv_ros.ros.bag_qos import bag_qos, ros_qos
from dynenv_ros.ros.qos import action_stream, recording_qos, sim_stream
from dynenv_ros.ros.tf import TF_STATIC_TOPIC, static_transforms, tf_static_qos
from ros_harness import spin_until

REPO = Path(__file__).resolve().parent.parent
SAMPLE_BAG = REPO / "bags" / "sample_2v2_realistic_30s"
TF_TYPE = "tf2_msgs/msg/TFMessage"
WORLD = "dynenv_msgs/msg/WorldState"
# What tf2_ros's StaticListenerQoS requests (tf2_ros is not among the PyPI wheels, so the listener is a plain
# subscription with the same profile).
TF2_STATIC_LISTENER_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=100,
                                     reliability=ReliabilityPolicy.RELIABLE,
                                     durability=DurabilityPolicy.TRANSIENT_LOCAL)


def discovered(reliability: QosReliability, durability: QosDurability, *, deadline: QosTime = INFINITE,
               lifespan: QosTime = INFINITE, lease: QosTime = INFINITE,
               liveliness: QosLiveliness = QosLiveliness.AUTOMATIC) -> Qos:
    """A profile as discovery reports a remote publisher's: no history."""
    return Qos(QosHistory.UNKNOWN, 0, reliability, durability, deadline, lifespan, liveliness, lease, False)


def essentials(profile: QoSProfile) -> tuple:
    """What decides matching, latching and loss: reliability, durability, history."""
    return profile.reliability, profile.durability, profile.history


# ------------------------------------------------------------------------------------------ the rule, without ROS
def test_a_latched_topic_plays_transient_local_and_keeps_its_messages_for_late_readers():
    offer = playback_qos("/tf_static", [discovered(QosReliability.RELIABLE, QosDurability.TRANSIENT_LOCAL)], 3)
    assert (offer.reliability, offer.durability, offer.history, offer.depth) == (
        QosReliability.RELIABLE, QosDurability.TRANSIENT_LOCAL, QosHistory.KEEP_LAST, 3)
    many = playback_qos("/team_a_0/action", [discovered(QosReliability.RELIABLE, QosDurability.TRANSIENT_LOCAL)],
                        10 * LATCHED_DEPTH_MAX)
    assert many.depth == LATCHED_DEPTH_MAX                  # bounded memory however long the bag


def test_a_volatile_topic_plays_lossless_keep_all_with_its_recorded_reliability():
    reliable = playback_qos("/world_state", [discovered(QosReliability.RELIABLE, QosDurability.VOLATILE)], 300)
    assert (reliable.reliability, reliable.durability, reliable.history) == (
        QosReliability.RELIABLE, QosDurability.VOLATILE, QosHistory.KEEP_ALL)
    best_effort = playback_qos("/scan", [discovered(QosReliability.BEST_EFFORT, QosDurability.VOLATILE)] * 2, 5)
    assert best_effort.reliability == QosReliability.BEST_EFFORT


def test_mixed_publishers_play_the_strongest_offer_so_every_original_reader_matches():
    millis = QosTime(0, 100_000_000)
    offer = playback_qos("/mixed", [
        discovered(QosReliability.BEST_EFFORT, QosDurability.VOLATILE, deadline=millis, lifespan=QosTime(2, 0),
                   lease=QosTime(3, 0), liveliness=QosLiveliness.MANUAL_BY_TOPIC),
        discovered(QosReliability.RELIABLE, QosDurability.TRANSIENT_LOCAL, deadline=QosTime(1, 0),
                   lifespan=QosTime(5, 0), lease=QosTime(1, 0))], 7)
    assert (offer.reliability, offer.durability) == (QosReliability.RELIABLE, QosDurability.TRANSIENT_LOCAL)
    assert (offer.deadline, offer.lifespan, offer.liveliness_lease_duration) == (millis, QosTime(5, 0), QosTime(1, 0))
    assert offer.liveliness == QosLiveliness.AUTOMATIC                   # they disagree: the default kind
    one = playback_qos("/manual", [discovered(QosReliability.RELIABLE, QosDurability.VOLATILE,
                                              liveliness=QosLiveliness.MANUAL_BY_NODE)], 1)
    assert one.liveliness == QosLiveliness.MANUAL_BY_TOPIC              # rclpy has no manual-by-node


def test_bags_without_usable_qos_play_the_documented_default_and_tf_static_stays_latched():
    assert playback_qos("/world_state", [], 10) == DEFAULT_PLAYBACK_QOS
    unknown = Qos(QosHistory.UNKNOWN, 0, QosReliability.UNKNOWN, QosDurability.UNKNOWN, QosTime(0, 0),
                  QosTime(0, 0), QosLiveliness.UNKNOWN, QosTime(0, 0), False)
    assert playback_qos("/world_state", [unknown], 10) == DEFAULT_PLAYBACK_QOS
    # The wrong metadata bags had before issue 28: /tf_static "reliable, volatile, keep_all".
    wrong = Qos(QosHistory.KEEP_ALL, 0, QosReliability.RELIABLE, QosDurability.VOLATILE, INFINITE, INFINITE,
                QosLiveliness.AUTOMATIC, INFINITE, False)
    for offered in ([], [wrong]):
        latched = playback_qos("/tf_static", offered, 1)
        assert (latched.durability, latched.history, latched.depth) == (
            QosDurability.TRANSIENT_LOCAL, QosHistory.KEEP_LAST, 1)
    assert playback_qos("/game_1/tf_static", [], 2).durability == QosDurability.TRANSIENT_LOCAL


# ------------------------------------------------------------------------------------- rclpy ↔ bag records
@pytest.mark.parametrize("profile", [tf_static_qos(), action_stream(), sim_stream(), QoSProfile(
    depth=3, reliability=ReliabilityPolicy.BEST_EFFORT, deadline=Duration(seconds=0.25),
    lifespan=Duration(seconds=2), liveliness=LivelinessPolicy.MANUAL_BY_TOPIC,
    liveliness_lease_duration=Duration(seconds=1))])
def test_profiles_convert_to_bag_records_and_back(profile):
    record = bag_qos(profile)
    assert ros_qos(record) == profile
    assert record.durability.name == profile.durability.name and record.depth == profile.depth


def test_the_recorder_subscribes_as_rosbag2_adapts_to_the_offers():
    reliable_latched = [tf_static_qos(), tf_static_qos()]
    assert recording_qos(reliable_latched).durability == DurabilityPolicy.TRANSIENT_LOCAL
    assert recording_qos(reliable_latched).reliability == ReliabilityPolicy.RELIABLE
    mixed = [tf_static_qos(), QoSProfile(depth=1, reliability=ReliabilityPolicy.BEST_EFFORT)]
    assert (recording_qos(mixed).reliability, recording_qos(mixed).durability) == (
        ReliabilityPolicy.BEST_EFFORT, DurabilityPolicy.VOLATILE)
    assert recording_qos(mixed).history == HistoryPolicy.KEEP_ALL


# ------------------------------------------------------------------------------- record, play, late TF listener
def _late_static_listener(make_node, executor, player) -> list:
    """A tf2-style static listener created only after the player has published everything."""
    from tf2_msgs.msg import TFMessage

    received: list = []
    listener = make_node("late_tf_listener")
    listener.create_subscription(TFMessage, TF_STATIC_TOPIC, received.append, TF2_STATIC_LISTENER_QOS)
    executor.add_node(listener)
    assert spin_until(executor, lambda: bool(received), 10.0), \
        f"a late tf listener got no static frames (player offers {player.qos_by_topic.get(TF_STATIC_TOPIC)})"
    return received


def _play(make_node, executor, bag: Path, topics_to_play: list[str]):
    from dynenv_ros.nodes.bag_player import BagPlayer

    overrides = [Parameter("bag", Parameter.Type.STRING, str(bag)), Parameter("rate", Parameter.Type.DOUBLE, 0.0)]
    if topics_to_play:
        overrides.append(Parameter("topics", Parameter.Type.STRING_ARRAY, topics_to_play))
    player = make_node(BagPlayer, exit_when_done=False, parameter_overrides=overrides)
    executor.add_node(player)
    assert spin_until(executor, lambda: player.finished, 20.0)
    return player


def test_a_fresh_recording_says_tf_static_is_transient_local_and_a_late_listener_gets_the_frames(
        tmp_path, make_node, executor):
    from dynenv_msgs.msg import WorldState
    from tf2_msgs.msg import TFMessage
    from dynenv_ros.nodes.recorder import Recorder
    from dynenv_ros.ros.conversions import sim_time

    # The simulator's way: /tf_static latched once before anyone listens, a volatile KEEP_ALL data stream.
    graph = make_node("fake_sim")
    sent = static_transforms(sim_time(0, 0.01))
    static = graph.create_publisher(TFMessage, TF_STATIC_TOPIC, tf_static_qos())
    static.publish(sent)
    world = graph.create_publisher(WorldState, topics.WORLD_STATE, sim_stream())
    bag = tmp_path / "latched"
    recorder = make_node(Recorder, exit_when_done=False, parameter_overrides=[
        Parameter("output", Parameter.Type.STRING, str(bag)),
        Parameter("topics", Parameter.Type.STRING_ARRAY, [TF_STATIC_TOPIC, topics.WORLD_STATE])])
    for node in (graph, recorder):
        executor.add_node(node)
    assert spin_until(executor, lambda: world.get_subscription_count() == 1
                      and recorder.counts.get(TF_STATIC_TOPIC) == 1, 10.0), recorder.counts
    for _ in range(3):
        world.publish(WorldState())
    assert spin_until(executor, lambda: recorder.counts.get(topics.WORLD_STATE) == 3, 10.0), recorder.counts
    recorder.finish()

    meta = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    offered = {t["topic_metadata"]["name"]: t["topic_metadata"]["offered_qos_profiles"]
               for t in meta["topics_with_message_count"]}
    assert [(p["reliability"], p["durability"]) for p in offered[TF_STATIC_TOPIC]] == [("reliable", "transient_local")]
    assert [(p["reliability"], p["durability"]) for p in offered[topics.WORLD_STATE]] == [("reliable", "volatile")]
    assert set(offered[TF_STATIC_TOPIC][0]) == {"history", "depth", "reliability", "durability", "deadline",
                                                "lifespan", "liveliness", "liveliness_lease_duration",
                                                "avoid_ros_namespace_conventions"}      # rosbag2 version 9's keys

    # Rebuilding metadata.yaml from the MCAP channels alone (dynenv-bag reindex) keeps the profiles.
    copy = tmp_path / "reindexed"
    shutil.copytree(bag, copy)
    (copy / "metadata.yaml").unlink()
    reindex(copy)
    rebuilt = yaml.safe_load((copy / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert {t["topic_metadata"]["name"]: t["topic_metadata"]["offered_qos_profiles"]
            for t in rebuilt["topics_with_message_count"]} == offered

    # The original publisher is gone: only the player can serve the static frames now.
    executor.remove_node(graph)
    graph.destroy_node()
    player = _play(make_node, executor, bag, [TF_STATIC_TOPIC, topics.WORLD_STATE])
    assert player.published == {TF_STATIC_TOPIC: 1, topics.WORLD_STATE: 3}
    assert player.qos_by_topic[TF_STATIC_TOPIC].durability == DurabilityPolicy.TRANSIENT_LOCAL
    assert essentials(player.qos_by_topic[topics.WORLD_STATE]) == essentials(sim_stream())
    received = _late_static_listener(make_node, executor, player)
    assert [(t.header.frame_id, t.child_frame_id, t.transform.rotation.z) for t in received[0].transforms] == [
        (t.header.frame_id, t.child_frame_id, pytest.approx(t.transform.rotation.z)) for t in sent.transforms]


def test_an_old_bag_with_wrong_or_no_qos_metadata_still_plays(tmp_path, make_node, executor):
    from dynenv_msgs.msg import WorldState
    from dynenv_ros.ros.conversions import sim_time

    bag = tmp_path / "old"
    with BagWriter(bag, dynenv_typestore()) as writer:
        writer.add_topic(TF_STATIC_TOPIC, TF_TYPE)              # the old default: reliable, volatile, keep_all
        writer.add_topic(topics.WORLD_STATE, WORLD, qos=())     # no profiles at all
        writer.write(TF_STATIC_TOPIC, 1, serialize_message(static_transforms(sim_time(0, 0.01))))
        writer.write(topics.WORLD_STATE, 2, serialize_message(WorldState()))
    player = _play(make_node, executor, bag, [])
    assert player.published == {TF_STATIC_TOPIC: 1, topics.WORLD_STATE: 1}
    assert essentials(player.qos_by_topic[topics.WORLD_STATE]) == essentials(sim_stream())
    assert len(_late_static_listener(make_node, executor, player)[0].transforms) == 2


@pytest.mark.skipif(not SAMPLE_BAG.is_dir(), reason="the sample bag is not in this checkout")
def test_the_sample_bag_serves_its_static_frames_to_a_late_listener(make_node, executor):
    player = _play(make_node, executor, SAMPLE_BAG, [TF_STATIC_TOPIC])
    assert player.published == {TF_STATIC_TOPIC: 1}
    assert _late_static_listener(make_node, executor, player)[0].transforms
