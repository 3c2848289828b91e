"""Bags without ``ros2 bag``: BagWriter, the recorder node (in process and as a process stopped by a signal), the
``dynenv-bag`` inspector (info, echo, render, export, damaged bags) and the bag player."""
from __future__ import annotations

import csv
import json
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import yaml
from PIL import Image
from rclpy.parameter import Parameter
from rclpy.serialization import deserialize_message, serialize_message
from rosbags.rosbag2 import Reader

from dynenv_ros.bags.inspect import bag_info, main as bag_main
from dynenv_ros.bags.messages import detection_rows, snapshot_from_msg
from dynenv_ros.bags.typestore import dynenv_typestore
from dynenv_ros.bags.writer import BagWriter
from dynenv_ros.ros import topics
from dynenv_ros.ros.interfaces import field_differences, sample_message
from dynenv_ros.ros.qos import sim_stream
from ros_harness import spin_until

REPO = Path(__file__).resolve().parent.parent
WORLD = "dynenv_msgs/msg/WorldState"
DETECTIONS = "dynenv_msgs/msg/DetectionArray"
FEEDBACK = "dynenv_msgs/msg/StepFeedback"
ACTION = "dynenv_msgs/msg/Action"
BAG_EPOCH_NS = 1_700_000_000_000_000_000   # bag times are wall-clock receive times


# ------------------------------------------------------------------------------------------------------ test bags
def simulated_messages(periods: int = 2) -> list[tuple[str, str, object, int]]:
    """(topic, type, message, bag time ns) of a short realistic game, in the order the simulator publishes."""
    from dynenv_ros.envs.soccer_session import SoccerSession
    from dynenv_ros.perception.params import load_preset
    from dynenv_ros.ros.conversions import action_msg, detection_array, sim_time, step_feedback, world_state
    from dynenv_ros.soccer.actions import IDLE
    from dynenv_ros.soccer.config import SoccerConfig

    session = SoccerSession(SoccerConfig(), load_preset("realistic"), seed=0)
    out: list[tuple[str, str, object, int]] = []
    for _ in range(periods):
        period = session.step()
        for frame in period.frames:
            stamp = sim_time(frame.tick, frame.snapshot.tick_period)
            at = BAG_EPOCH_NS + frame.tick * 10_000_000
            out.append((topics.WORLD_STATE, WORLD, world_state(frame.snapshot, stamp), at))
            for robot_id, seen in enumerate(frame.robots):
                name = session.names[robot_id]
                msg = detection_array(seen.detections, robot_id=robot_id, robot_name=name,
                                      episode_id=period.episode_id, motion_period=period.motion_period,
                                      frame_index=frame.frame_index, frames_per_period=len(period.frames),
                                      head_yaw=seen.head_yaw, fallen=seen.fallen, penalized=seen.penalized,
                                      kicking=seen.kicking, ball_owner=seen.ball_owner,
                                      ball_owner_seconds=seen.ball_owner_seconds,
                                      game_seconds_remaining=seen.game_seconds_remaining, stamp=stamp)
                out.append((topics.detections(name), DETECTIONS, msg, at + 1 + robot_id))
        end = sim_time(period.frames[-1].tick, 0.01)
        at = BAG_EPOCH_NS + period.frames[-1].tick * 10_000_000 + 100
        for robot_id, feedback in enumerate(period.feedback):
            name = session.names[robot_id]
            out.append((topics.feedback(name), FEEDBACK, step_feedback(
                robot_id=robot_id, episode_id=period.episode_id, motion_period=period.motion_period,
                rewards=feedback.rewards, terminated=period.terminated, truncated=period.truncated,
                seen_object_ids=feedback.seen_object_ids, landmarks_seen=feedback.landmarks_seen, stamp=end),
                at + robot_id))
            out.append((topics.action(name), ACTION, action_msg(
                IDLE, robot_id=robot_id, episode_id=period.episode_id, motion_period=period.motion_period + 1,
                stamp=end), at + 10 + robot_id))
    return out


def write_bag(path: Path, messages: list[tuple[str, str, object, int]]) -> Path:
    with BagWriter(path, dynenv_typestore()) as bag:
        for topic, msgtype, message, at in messages:
            bag.add_topic(topic, msgtype)
            bag.write(topic, at, serialize_message(message))
    return path


@pytest.fixture(scope="module")
def game() -> list[tuple[str, str, object, int]]:
    return simulated_messages()


@pytest.fixture(scope="module")
def game_bag(tmp_path_factory, game) -> Path:
    return write_bag(tmp_path_factory.mktemp("bags") / "game", game)


def counts_of(messages) -> dict[str, int]:
    counts: dict[str, int] = {}
    for topic, *_ in messages:
        counts[topic] = counts.get(topic, 0) + 1
    return counts


def run_cli(capsys, *argv: str) -> tuple[int, str, str]:
    status = bag_main([str(a) for a in argv])
    captured = capsys.readouterr()
    return status, captured.out, captured.err


# --------------------------------------------------------------------------------------------------------- writer
def test_writer_round_trip_equals_decoded_fields(tmp_path):
    from dynenv_msgs.msg import DetectionArray, WorldState

    written = [("/team_a_0/detections", DETECTIONS, sample_message(DetectionArray, seed), 1_000 + seed)
               for seed in range(4)]
    written += [("/world_state", WORLD, sample_message(WorldState, seed), 2_000 + seed) for seed in range(4)]
    write_bag(tmp_path / "bag", written)
    store = dynenv_typestore()
    with Reader(tmp_path / "bag") as reader:
        assert {c.topic: c.msgtype for c in reader.connections} == {"/team_a_0/detections": DETECTIONS,
                                                                     "/world_state": WORLD}
        assert all(c.digest == store.hash_rihs01(c.msgtype) for c in reader.connections)
        read = [(c.topic, t, store.deserialize_cdr(raw, c.msgtype)) for c, t, raw in reader.messages()]
    assert [(topic, t) for topic, t, _ in read] == [(topic, t) for topic, _, _, t in written]
    for (_, _, message, _), (_, _, decoded) in zip(written, read):
        assert field_differences(message, decoded) == []


def test_writer_refuses_an_existing_path_and_closes_twice(tmp_path):
    (tmp_path / "taken").mkdir()
    with pytest.raises(FileExistsError, match="already exists"):
        BagWriter(tmp_path / "taken", dynenv_typestore())
    bag = BagWriter(tmp_path / "new", dynenv_typestore())
    bag.add_topic("/world_state", WORLD)
    with pytest.raises(KeyError, match="unknown to the typestore"):
        bag.add_topic("/other", "nobody_msgs/msg/Nothing")
    with pytest.raises(KeyError, match="add_topic first"):
        bag.write("/nowhere", 1, b"")
    bag.close()
    bag.close()
    with pytest.raises(RuntimeError, match="closed"):
        bag.write("/world_state", 1, b"")
    assert (tmp_path / "new" / "metadata.yaml").is_file()


# ------------------------------------------------------------------------------------------------------- recorder
def test_recorder_in_process_records_every_message(tmp_path, make_node, executor, game):
    from dynenv_msgs.msg import DetectionArray, WorldState
    from dynenv_ros.nodes.recorder import Recorder

    sent = {topics.WORLD_STATE: [m for t, _, m, _ in game if t == topics.WORLD_STATE],
            "/team_a_0/detections": [m for t, _, m, _ in game if t == "/team_a_0/detections"]}
    source = make_node("fake_sim")
    publishers = {topics.WORLD_STATE: source.create_publisher(WorldState, topics.WORLD_STATE, sim_stream()),
                  "/team_a_0/detections": source.create_publisher(DetectionArray, "/team_a_0/detections",
                                                                  sim_stream())}
    bag = tmp_path / "recorded"
    recorder = make_node(Recorder, exit_when_done=False,
                         parameter_overrides=[Parameter("output", Parameter.Type.STRING, str(bag))])
    for node in (source, recorder):
        executor.add_node(node)
    assert spin_until(executor, lambda: all(p.get_subscription_count() == 1 for p in publishers.values()), 10.0), \
        recorder.subscribed
    for topic, messages in sent.items():
        for message in messages:
            publishers[topic].publish(message)
    expected = {topic: len(messages) for topic, messages in sent.items()}
    assert spin_until(executor, lambda: recorder.counts == expected, 10.0), recorder.counts
    recorder.finish()
    assert {t["name"]: t["count"] for t in bag_info(bag)["topics"]} == expected
    store = dynenv_typestore()
    with Reader(bag) as reader:
        decoded = {topic: [] for topic in sent}
        for connection, _, data in reader.messages():
            decoded[connection.topic].append(store.deserialize_cdr(data, connection.msgtype))
    # Fields, not bytes: the DDS serializer leaves CDR padding bytes undefined, so bytes differ between paths.
    # Expected values went through CDR once too (float32 fields of the sent Python objects are not rounded yet).
    for topic, messages in sent.items():
        wire = [deserialize_message(serialize_message(m), type(m)) for m in messages]
        assert [field_differences(w, d) for w, d in zip(wire, decoded[topic])] == [[]] * len(messages)


@pytest.mark.parametrize("stop", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_recorder_process_finishes_the_bag_on_a_signal(stop, tmp_path, make_node, executor, game):
    from dynenv_msgs.msg import DetectionArray, WorldState

    sent = [(t, m) for t, _, m, _ in game if t in (topics.WORLD_STATE, "/team_a_0/detections")]
    source = make_node("fake_sim")
    publishers = {topics.WORLD_STATE: source.create_publisher(WorldState, topics.WORLD_STATE, sim_stream()),
                  "/team_a_0/detections": source.create_publisher(DetectionArray, "/team_a_0/detections",
                                                                  sim_stream())}
    executor.add_node(source)
    bag = tmp_path / "recorded"
    process = subprocess.Popen([sys.executable, "-m", "dynenv_ros.nodes.recorder", "--ros-args",
                                "-p", f"output:={bag}"], cwd=REPO, stdout=subprocess.PIPE,
                               stderr=subprocess.STDOUT, text=True)
    try:
        subscribed = spin_until(executor, lambda: all(p.get_subscription_count() == 1
                                                      for p in publishers.values()), 30.0)
        assert subscribed, "the recorder did not subscribe"
        for topic, message in sent:
            publishers[topic].publish(message)
        # Stopped right after publishing, like the main job's graph does when the simulator exits: the recorder
        # must drain what is already on its way before finishing the bag. (Waiting for acknowledgements here would
        # cost Fast DDS's 3 s heartbeat period.)
        process.send_signal(stop)
        output, _ = process.communicate(timeout=20)
    finally:
        if process.poll() is None:
            process.kill()
            process.communicate()
    assert process.returncode == 0, output
    assert "finished" in output, output
    assert {t["name"]: t["count"] for t in bag_info(bag)["topics"]} == counts_of(sent)


def test_recorder_signalled_while_it_is_being_built_still_finishes_the_bag(tmp_path):
    """A publisher can see the recorder's subscriptions, send, and signal before the recorder's constructor has
    returned (the old handler then raised KeyboardInterrupt inside the constructor: exit 0, bag never finished).
    Here the signal is sent from the constructor itself, after the subscriptions exist."""
    bag = tmp_path / "early"
    script = ("import os, signal\n"
              "from dynenv_ros.nodes.recorder import Recorder\n"
              "from dynenv_ros.ros.signal_runner import run_draining\n"
              "class Early(Recorder):\n"
              "    def __init__(self, **kw):\n"
              "        super().__init__(**kw)\n"
              "        os.kill(os.getpid(), signal.SIGINT)\n"
              f"raise SystemExit(run_draining(Early, ['--ros-args', '-p', 'output:={bag}']))\n")
    done = subprocess.run([sys.executable, "-c", script], cwd=REPO, capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    assert "finished" in done.stdout + done.stderr, done.stderr
    assert bag_info(bag)["message_count"] == 0


def test_recorder_cli_stops_after_duration_and_refuses_existing_output(tmp_path):
    bag = tmp_path / "empty"
    done = subprocess.run([sys.executable, "-c", "from dynenv_ros.nodes.recorder import cli_main; "
                           f"raise SystemExit(cli_main(['--output', {str(bag)!r}, '--duration', '0.3', "
                           "'--topics', '/nothing_here']))"], cwd=REPO, capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    info = bag_info(bag)
    assert info["message_count"] == 0 and info["topics"] == []
    again = subprocess.run([sys.executable, "-m", "dynenv_ros.nodes.recorder", "--ros-args", "-p",
                            f"output:={bag}"], cwd=REPO, capture_output=True, text=True, timeout=60)
    assert again.returncode == 2
    assert "already exists" in again.stderr + again.stdout


# ------------------------------------------------------------------------------------------------------ inspector
def test_info_text_and_json(capsys, game_bag, game):
    status, out, err = run_cli(capsys, "info", game_bag)
    assert status == 0, err
    assert "/world_state" in out and WORLD in out and "Duration" in out
    status, out, _ = run_cli(capsys, "info", game_bag, "--json")
    assert status == 0
    info = json.loads(out)
    assert {t["name"]: t["count"] for t in info["topics"]} == counts_of(game)
    assert info["message_count"] == len(game)
    assert info["start_ns"] == min(t for *_, t in game) and info["end_ns"] == max(t for *_, t in game)
    world = next(t for t in info["topics"] if t["name"] == topics.WORLD_STATE)
    assert world["type"] == WORLD
    times = [t for topic, *_, t in game if topic == topics.WORLD_STATE]
    assert world["rate_hz"] == pytest.approx((len(times) - 1) / ((times[-1] - times[0]) / 1e9))


def test_echo_yaml_json_and_limit(capsys, game_bag, game):
    sent = [m for t, _, m, _ in game if t == topics.WORLD_STATE]
    status, out, err = run_cli(capsys, "echo", game_bag, "--topic", topics.WORLD_STATE, "--limit", "2")
    assert status == 0, err
    documents = [d for d in yaml.safe_load_all(out) if d is not None]
    assert len(documents) == 2
    assert documents[1]["message"]["tick"] == sent[1].tick
    assert len(documents[0]["message"]["objects"]) == len(sent[0].objects)
    status, out, _ = run_cli(capsys, "echo", game_bag, "--topic", "/team_a_0/detections", "--format", "json")
    assert status == 0
    records = [json.loads(line) for line in out.splitlines()]
    arrays = [m for t, _, m, _ in game if t == "/team_a_0/detections"]
    assert len(records) == len(arrays)
    first = records[0]["message"]
    assert first["header"]["frame_id"] == "team_a_0/camera"
    assert len(first["detections"]) == len(arrays[0].detections)
    yaws = [d["yaw"] for r in records for d in r["message"]["detections"]]
    nan_yaws = sum(1 for a in arrays for d in a.detections if d.yaw != d.yaw)
    assert nan_yaws > 0 and yaws.count(None) == nan_yaws   # NaN (undefined yaw) is null in JSON
    status, _, err = run_cli(capsys, "echo", game_bag, "--topic", "/nope")
    assert status == 2 and "/nope" in err and "/world_state" in err


def test_render_gif_has_a_frame_per_world_state(capsys, tmp_path, game_bag, game):
    worlds = sum(1 for t, *_ in game if t == topics.WORLD_STATE)
    status, out, err = run_cli(capsys, "render", game_bag, "--out", tmp_path / "game.gif", "--fps", "20",
                               "--pixels-per-metre", "20")
    assert status == 0, err
    status, _, err = run_cli(capsys, "render", game_bag, "--out", tmp_path / "seen.gif", "--robot", "team_a_0",
                             "--pixels-per-metre", "20")
    assert status == 0, err
    with Image.open(tmp_path / "game.gif") as plain, Image.open(tmp_path / "seen.gif") as seen:
        assert plain.n_frames == seen.n_frames == worlds
        assert plain.size == seen.size
        plain.seek(0)
        seen.seek(0)
        assert np.any(np.asarray(plain.convert("RGB")) != np.asarray(seen.convert("RGB"))), "no overlay drawn"
    status, _, err = run_cli(capsys, "render", game_bag, "--out", tmp_path / "x.gif", "--robot", "team_z_9")
    assert status == 2 and "team_z_9" in err


def test_bag_messages_convert_to_core_records(game):
    from dynenv_msgs.msg import WorldState
    from rclpy.serialization import serialize_message as ser
    from dynenv_ros.ros.conversions import snapshot_from_msg as ros_snapshot

    store = dynenv_typestore()
    world = next(m for t, _, m, _ in game if t == topics.WORLD_STATE)
    wire = deserialize_message(ser(world), WorldState)   # float32 fields rounded as in any bag
    # repr: NaN goal_x/goal_y compare unequal as values
    assert repr(snapshot_from_msg(store.deserialize_cdr(ser(world), WORLD))) == repr(ros_snapshot(wire))
    array = next(m for t, _, m, _ in game if t == "/team_a_0/detections")
    rows = detection_rows(store.deserialize_cdr(ser(array), DETECTIONS).detections)
    assert len(rows) == len(array.detections)
    assert set(rows["true_id"]) == {-2} and set(rows["true_class"]) == {0}
    assert rows["x"][0] == pytest.approx(array.detections[0].position.x)


def test_export_csv_and_npz(capsys, tmp_path, game_bag, game):
    worlds = [m for t, _, m, _ in game if t == topics.WORLD_STATE]
    arrays = [m for t, _, m, _ in game if t.endswith("/detections")]
    n_feedback = sum(1 for t, *_ in game if t.endswith("/feedback"))
    n_actions = sum(1 for t, *_ in game if t.endswith("/action"))
    status, _, err = run_cli(capsys, "export", game_bag, "--out", tmp_path / "csv")
    assert status == 0, err
    tables = {}
    for kind in ("world_state", "detections", "feedback", "actions"):
        with open(tmp_path / "csv" / f"{kind}.csv", newline="") as stream:
            tables[kind] = list(csv.DictReader(stream))
    assert len(tables["world_state"]) == sum(len(w.objects) for w in worlds)
    assert len(tables["detections"]) == sum(len(a.detections) for a in arrays)
    assert len(tables["feedback"]) == n_feedback and len(tables["actions"]) == n_actions
    first = tables["world_state"][0]
    assert int(first["tick"]) == worlds[0].tick and int(first["id"]) == worlds[0].objects[0].id
    assert float(first["x"]) == pytest.approx(worlds[0].objects[0].x)
    assert {row["robot"] for row in tables["detections"]} == {"team_a_0", "team_a_1", "team_b_0", "team_b_1"}
    # the robot's own kick and the GameController's values, repeated on each of a message's rows
    expected = [(str(a.self_kicking), str(a.ball_owner), str(np.float32(a.ball_owner_seconds)),
                 str(np.float32(a.game_seconds_remaining))) for a in arrays for _ in a.detections]
    got = [(r["self_kicking"], r["ball_owner"], r["ball_owner_seconds"], r["game_seconds_remaining"])
           for r in tables["detections"]]
    assert sorted(got) == sorted(expected) and {g[1] for g in got} == {"1", "-1"}
    status, _, err = run_cli(capsys, "export", game_bag, "--out", tmp_path / "npz", "--format", "npz")
    assert status == 0, err
    with np.load(tmp_path / "npz" / "detections.npz") as detections, \
            np.load(tmp_path / "npz" / "world_state.npz") as world:
        assert len(detections["class_id"]) == len(tables["detections"])
        assert detections["robot"][0] == tables["detections"][0]["robot"]
        assert detections["ball_owner"].dtype == np.int8 and detections["game_seconds_remaining"].dtype == np.float32
        assert world["x"][0] == pytest.approx(worlds[0].objects[0].x)
        assert world["stamp_ns"][0] == worlds[0].header.stamp.sec * 10**9 + worlds[0].header.stamp.nanosec


def test_damaged_or_missing_bag_is_exit_2_without_traceback(capsys, tmp_path, game_bag):
    import shutil

    damaged = tmp_path / "damaged"
    shutil.copytree(game_bag, damaged)
    mcap = next(damaged.glob("*.mcap"))
    mcap.write_bytes(mcap.read_bytes()[: mcap.stat().st_size // 2])
    for argv in (["info", damaged], ["echo", damaged, "--topic", "/world_state"],
                 ["render", damaged, "--out", tmp_path / "x.gif"], ["export", damaged, "--out", tmp_path / "e"],
                 ["info", tmp_path / "missing"]):
        status, _, err = run_cli(capsys, *argv)
        assert status == 2, argv
        assert err.startswith("dynenv-bag: error:") and "Traceback" not in err, err
    done = subprocess.run([sys.executable, "-m", "dynenv_ros.bags.inspect", "info", str(damaged)], cwd=REPO,
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == 2 and "Traceback" not in done.stderr and "damaged" in done.stderr


# --------------------------------------------------------------------------------------------------------- player
def test_player_republishes_every_message(make_node, executor, game_bag, game):
    from dynenv_msgs.msg import DetectionArray, WorldState
    from dynenv_ros.nodes.bag_player import BagPlayer

    played = {topics.WORLD_STATE: WorldState, "/team_b_1/detections": DetectionArray}
    received: dict[str, list[bytes]] = {topic: [] for topic in played}
    listener = make_node("listener")
    for topic, cls in played.items():
        listener.create_subscription(cls, topic, received[topic].append, sim_stream(), raw=True)
    player = make_node(BagPlayer, exit_when_done=False, parameter_overrides=[
        Parameter("bag", Parameter.Type.STRING, str(game_bag)), Parameter("rate", Parameter.Type.DOUBLE, 0.0),
        Parameter("topics", Parameter.Type.STRING_ARRAY, list(played)),
        Parameter("wait_for_subscribers", Parameter.Type.INTEGER, 1)])
    for node in (listener, player):
        executor.add_node(node)
    expected = {topic: [m for t, _, m, _ in game if t == topic] for topic in played}
    assert spin_until(executor, lambda: player.finished and all(len(received[t]) == len(expected[t])
                                                               for t in played), 20.0), \
        {t: len(v) for t, v in received.items()}
    for topic, cls in played.items():   # fields, not bytes: CDR padding bytes are undefined
        wire = [deserialize_message(serialize_message(m), cls) for m in expected[topic]]
        assert [field_differences(w, deserialize_message(r, cls)) for w, r in zip(wire, received[topic])] \
            == [[]] * len(wire)
    assert player.published == {topic: len(messages) for topic, messages in expected.items()}


def test_player_rebuilds_messages_recorded_with_an_older_definition(make_node, executor):
    """The old sample bag's DetectionArrays predate self_kicking and the GameController fields: played raw, their bytes
    would be misread; the player rebuilds them as the installed type (old fields equal, new ones at defaults)."""
    from dynenv_msgs.msg import DetectionArray, WorldState
    from dynenv_ros.bags.inspect import echo
    from dynenv_ros.nodes.bag_player import BagPlayer

    sample = REPO / "test" / "data" / "bag_before_checksums_2v2_30s"
    played = {"/team_b_0/detections": DetectionArray, topics.WORLD_STATE: WorldState}
    received: dict[str, list] = {topic: [] for topic in played}
    listener = make_node("old_listener")
    for topic, cls in played.items():
        listener.create_subscription(cls, topic, received[topic].append, sim_stream())
    player = make_node(BagPlayer, exit_when_done=False, parameter_overrides=[
        Parameter("bag", Parameter.Type.STRING, str(sample)), Parameter("rate", Parameter.Type.DOUBLE, 0.0),
        Parameter("topics", Parameter.Type.STRING_ARRAY, list(played)),
        Parameter("wait_for_subscribers", Parameter.Type.INTEGER, 1)])
    assert set(player.converted) == {"/team_b_0/detections"}      # WorldState is unchanged: played raw
    for node in (listener, player):
        executor.add_node(node)
    assert spin_until(executor, lambda: player.finished and len(received["/team_b_0/detections"]) == 305
                      and len(received[topics.WORLD_STATE]) == 305, 30.0), {t: len(v) for t, v in received.items()}
    recorded = [r["message"] for r in echo(sample, "/team_b_0/detections")]
    for old, new in zip(recorded, received["/team_b_0/detections"]):
        assert (new.robot_id, new.episode_id, new.motion_period, new.frame_index, new.header.frame_id) == (
            old["robot_id"], old["episode_id"], old["motion_period"], old["frame_index"], old["header"]["frame_id"])
        assert (new.self_fallen, new.self_penalized) == (old["self_fallen"], old["self_penalized"])
        assert new.head_yaw == pytest.approx(old["head_yaw"])
        assert [d.class_id for d in new.detections] == [d["class_id"] for d in old["detections"]]
        assert [d.position.x for d in new.detections] == pytest.approx([d["position"]["x"] for d in old["detections"]])
        assert (new.self_kicking, new.ball_owner, new.ball_owner_seconds, new.game_seconds_remaining) == (
            False, 0, 0.0, 0.0)


def test_player_keeps_the_bag_timing(make_node, executor, tmp_path, game):
    from dynenv_ros.nodes.bag_player import BagPlayer

    worlds = [(t, ty, m, BAG_EPOCH_NS + i * 100_000_000) for i, (t, ty, m, _) in enumerate(game)
              if t == topics.WORLD_STATE][:4]
    bag = write_bag(tmp_path / "timed", worlds)   # 4 messages 0.1 s apart: 0.3 s at rate 1, 0.15 s at rate 2
    player = make_node(BagPlayer, exit_when_done=False, parameter_overrides=[
        Parameter("bag", Parameter.Type.STRING, str(bag)), Parameter("rate", Parameter.Type.DOUBLE, 2.0)])
    executor.add_node(player)
    started = time.monotonic()
    assert spin_until(executor, lambda: player.finished, 10.0)
    assert 0.14 <= time.monotonic() - started < 2.0
    assert player.published == {topics.WORLD_STATE: 4}


def test_player_process_exits_0_when_done_and_2_on_a_bad_bag(tmp_path, game_bag):
    done = subprocess.run([sys.executable, "-m", "dynenv_ros.nodes.bag_player", "--ros-args", "-p",
                           f"bag:={game_bag}", "-p", "rate:=0.0"], cwd=REPO, capture_output=True, text=True,
                          timeout=60)
    assert done.returncode == 0, done.stderr
    bad = subprocess.run([sys.executable, "-m", "dynenv_ros.nodes.bag_player", "--ros-args", "-p",
                          f"bag:={tmp_path / 'missing'}"], cwd=REPO, capture_output=True, text=True, timeout=60)
    assert bad.returncode == 2 and "no bag at" in bad.stderr + bad.stdout
