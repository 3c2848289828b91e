"""Crash-safe bags and honest bag tools: a recorder killed with SIGKILL leaves a bag ``dynenv-bag reindex`` makes
readable with at most ~1 s lost; flipped bytes are found, named and skipped only when asked; topics of unknown
types are skipped with a notice (inspector and player); render's options are bounded."""
from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

import pytest
from rclpy.parameter import Parameter
from rclpy.serialization import serialize_message
from rosbags.highlevel import AnyReader
from rosbags.rosbag2 import StoragePlugin, Writer

from dynenv_ros.bags import inspect as bag_inspect
from dynenv_ros.bags.inspect import bag_info, main as bag_main
from dynenv_ros.bags.typestore import dynenv_typestore
from dynenv_ros.ros import topics
from dynenv_ros.ros.qos import sim_stream
from ros_harness import spin_until
from test_bags import WORLD, run_cli, simulated_messages, write_bag

REPO = Path(__file__).resolve().parent.parent


@pytest.fixture(scope="module")
def game() -> list[tuple[str, str, object, int]]:
    return simulated_messages(periods=6)


def anyreader_count(bag: Path) -> int:
    with AnyReader([bag]) as reader:
        return sum(1 for _ in reader.messages())


# --------------------------------------------------------------------------------------------------- kill -9
def test_recorder_killed_with_sigkill_is_recovered_by_reindex_losing_at_most_a_second(tmp_path, make_node,
                                                                                      executor, game):
    from dynenv_msgs.msg import WorldState

    worlds = [m for t, _, m, _ in game if t == topics.WORLD_STATE]
    source = make_node("fake_sim")
    publisher = source.create_publisher(WorldState, topics.WORLD_STATE, sim_stream())
    executor.add_node(source)
    bag = tmp_path / "killed"
    process = subprocess.Popen([sys.executable, "-m", "dynenv_ros.nodes.recorder", "--ros-args",
                                "-p", f"output:={bag}"], cwd=REPO, stdout=subprocess.PIPE,
                               stderr=subprocess.STDOUT, text=True)
    sent: list[float] = []   # when each message was published
    try:
        assert spin_until(executor, lambda: publisher.get_subscription_count() == 1, 30.0), "no subscription"
        started = time.monotonic()
        while time.monotonic() - started < 3.0:   # 50 Hz for 3 s: ~150 world states, far below a 1 MiB chunk
            publisher.publish(worlds[len(sent) % len(worlds)])
            sent.append(time.monotonic())
            time.sleep(0.02)
        process.kill()   # SIGKILL while messages are still arriving
        killed = time.monotonic()
        process.communicate(timeout=20)
    finally:
        if process.poll() is None:
            process.kill()
            process.communicate()
    assert not (bag / "metadata.yaml").exists()
    refused = subprocess.run([sys.executable, "-m", "dynenv_ros.bags.inspect", "info", str(bag)], cwd=REPO,
                             capture_output=True, text=True, timeout=60)
    assert refused.returncode == 2 and "Traceback" not in refused.stderr
    assert "reindex" in refused.stderr, refused.stderr
    done = subprocess.run([sys.executable, "-m", "dynenv_ros.bags.inspect", "reindex", str(bag)], cwd=REPO,
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    recovered = int(done.stdout.split("recovered ")[1].split()[0])
    # at most ~1 s lost: every message published more than 1 s before the kill is in the bag
    assert sum(1 for t in sent if t < killed - 1.0) <= recovered <= len(sent), (recovered, len(sent), done.stdout)
    assert anyreader_count(bag) == recovered
    info = bag_info(bag)
    assert info["message_count"] == recovered
    assert {t["name"]: t["count"] for t in info["topics"]} == {topics.WORLD_STATE: recovered}


def test_reindex_of_a_complete_bag_changes_nothing(capsys, tmp_path, game):
    bag = write_bag(tmp_path / "whole", game)
    before = (bag / "whole.mcap").read_bytes()
    status, out, err = run_cli(capsys, "reindex", bag)
    assert status == 0, err
    assert "already complete" in out and f"{len(game)} messages" in out
    assert (bag / "whole.mcap").read_bytes() == before


# --------------------------------------------------------------------------------------------- flipped bytes
@pytest.fixture
def long_bag(tmp_path, game) -> tuple[Path, list]:
    """The game six times over (~1.3 MB, several chunks), and a pristine copy of its MCAP file."""
    span = max(at for *_, at in game) - min(at for *_, at in game) + 10_000_000
    messages = [(t, ty, m, at + k * span) for k in range(6) for t, ty, m, at in game]
    bag = write_bag(tmp_path / "long", messages)
    pristine = tmp_path / "pristine.mcap"
    pristine.write_bytes((bag / "long.mcap").read_bytes())
    return bag, messages, pristine


def test_flipped_bytes_are_named_and_skipped_only_with_ignore_damage(capsys, tmp_path, long_bag):
    import json

    bag, messages, pristine = long_bag
    mcap_file = bag / "long.mcap"
    data = bytearray(mcap_file.read_bytes())
    start = len(data) // 2
    for i in range(start, start + 20_000):   # 20 KB flipped in the middle
        data[i] ^= 0xFF
    mcap_file.write_bytes(bytes(data))
    for argv in (["info"], ["echo", "--topic", topics.WORLD_STATE], ["export", "--out", tmp_path / "e"],
                 ["render", "--out", tmp_path / "x.gif", "--pixels-per-metre", "10"]):
        status, _, err = run_cli(capsys, argv[0], bag, *argv[1:])
        assert status == 2, argv
        assert "damaged" in err and "--ignore-damage" in err, err
        assert "Traceback" not in err and len(err.strip().splitlines()) == 1, err

    from dynenv_ros.bags.mcap import scan

    chunks = scan(pristine).chunks
    hit = [c for c in chunks if c.start < start + 20_000 and start < c.end]
    survivors = len(messages) - sum(c.message_count for c in hit)
    lost = len(messages) - survivors
    assert len(chunks) >= 4 and 0 < survivors < len(messages)
    status, _, err = run_cli(capsys, "info", bag)
    assert f"{lost} messages" in err, err   # the refusal says how much is affected
    status, out, err = run_cli(capsys, "info", bag, "--json", "--ignore-damage")
    assert status == 0, err
    assert f"{lost} messages" in err and "notice" in err
    assert json.loads(out)["message_count"] == survivors
    status, _, err = run_cli(capsys, "export", bag, "--out", tmp_path / "e", "--ignore-damage")
    assert status == 0 and "damaged" in err
    # reindex repairs the bag itself only when told to leave the damaged chunks out
    status, _, err = run_cli(capsys, "reindex", bag)
    assert status == 2 and "--ignore-damage" in err
    status, out, err = run_cli(capsys, "reindex", bag, "--ignore-damage")
    assert status == 0, err
    assert f"recovered {survivors} messages" in out and f"{lost} messages" in out
    assert anyreader_count(bag) == survivors
    status, out, _ = run_cli(capsys, "info", bag, "--json")
    assert status == 0 and json.loads(out)["message_count"] == survivors


def test_a_bag_cut_short_mid_chunk_reads_only_with_ignore_damage(capsys, long_bag):
    """A crash's truncated end (the same bytes a killed recorder leaves): refused with the reindex hint, readable
    with --ignore-damage without changing the file."""
    import json

    bag, _, pristine = long_bag
    mcap_file = bag / "long.mcap"
    cut = mcap_file.stat().st_size * 2 // 3
    mcap_file.write_bytes(mcap_file.read_bytes()[:cut])
    status, _, err = run_cli(capsys, "info", bag)
    assert status == 2 and "reindex" in err and "not finished" in err, err
    status, out, err = run_cli(capsys, "info", bag, "--json", "--ignore-damage")
    assert status == 0, err
    from dynenv_ros.bags.mcap import scan

    whole = [c for c in scan(pristine).chunks if c.end <= cut]
    assert json.loads(out)["message_count"] == sum(c.message_count for c in whole) > 0
    assert mcap_file.stat().st_size == cut


# ------------------------------------------------------------------------------------------------ unknown types
@pytest.fixture
def foreign_bag(tmp_path, game) -> Path:
    """World states plus a type that is decodable from its embedded definition but not installed (/thing) and
    one with no definition at all (/ghost)."""
    bag = tmp_path / "foreign"
    store = dynenv_typestore()
    with Writer(bag, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        world = writer.add_connection(topics.WORLD_STATE, WORLD, typestore=store)
        thing = writer.add_connection("/thing", "foo_msgs/msg/Thing", msgdef="int32 x\n",
                                      rihs01="RIHS01_477581b927940c98c1c5e542e05f6344aa7726c5f31ca698f2b3626f45204ded")
        ghost = writer.add_connection("/ghost", "ghost_msgs/msg/Ghost", msgdef="", rihs01="RIHS01_" + "1" * 64)
        for topic, _, message, at in game:
            if topic == topics.WORLD_STATE:
                writer.write(world, at, serialize_message(message))
                writer.write(thing, at, b"\x00\x01\x00\x00\x05\x00\x00\x00")
                writer.write(ghost, at, b"\x00\x01\x00\x00\x07\x00\x00\x00")
    return bag


def test_unknown_types_are_skipped_with_a_notice_by_the_inspector(capsys, tmp_path, foreign_bag, game):
    n_worlds = sum(1 for t, *_ in game if t == topics.WORLD_STATE)
    status, _, err = run_cli(capsys, "export", foreign_bag, "--out", tmp_path / "e")
    assert status == 0, err
    assert "notice" in err and "/ghost" in err and "ghost_msgs/msg/Ghost" in err and "Traceback" not in err
    worlds = [m for t, _, m, _ in game if t == topics.WORLD_STATE]
    rows = (tmp_path / "e" / "world_state.csv").read_text().splitlines()
    assert len(rows) == 1 + sum(len(w.objects) for w in worlds)
    status, out, err = run_cli(capsys, "info", foreign_bag, "--json")
    assert status == 0, err
    import json
    counts = {t["name"]: t["count"] for t in json.loads(out)["topics"]}
    assert counts == {topics.WORLD_STATE: n_worlds, "/thing": n_worlds, "/ghost": n_worlds}
    status, out, err = run_cli(capsys, "echo", foreign_bag, "--topic", "/thing", "--limit", "1")
    assert status == 0 and "x: 5" in out, err
    status, _, err = run_cli(capsys, "echo", foreign_bag, "--topic", "/ghost")
    assert status == 2 and "cannot be decoded" in err
    status, out, err = run_cli(capsys, "render", foreign_bag, "--out", tmp_path / "r.gif", "--pixels-per-metre", "5",
                               "--stride", "10")
    assert status == 0, err


def test_the_player_skips_topics_it_cannot_publish_and_plays_the_rest(make_node, executor, foreign_bag, game):
    from dynenv_msgs.msg import WorldState
    from dynenv_ros.nodes.bag_player import BagPlayer

    received: list[bytes] = []
    listener = make_node("listener")
    listener.create_subscription(WorldState, topics.WORLD_STATE, received.append, sim_stream(), raw=True)
    player = make_node(BagPlayer, exit_when_done=False, parameter_overrides=[
        Parameter("bag", Parameter.Type.STRING, str(foreign_bag)), Parameter("rate", Parameter.Type.DOUBLE, 0.0),
        Parameter("wait_for_subscribers", Parameter.Type.INTEGER, 1)])
    assert set(player.skipped) == {"/thing", "/ghost"}
    assert "foo_msgs" in player.skipped["/thing"] and "unknown" in player.skipped["/ghost"]
    for node in (listener, player):
        executor.add_node(node)
    n_worlds = sum(1 for t, *_ in game if t == topics.WORLD_STATE)
    assert spin_until(executor, lambda: player.finished and len(received) == n_worlds, 20.0), len(received)
    assert player.published == {topics.WORLD_STATE: n_worlds}


# ------------------------------------------------------------------------------------------------- render bounds
def test_render_refuses_unbounded_options_in_one_line(capsys, tmp_path, monkeypatch, game):
    bag = write_bag(tmp_path / "small", game)
    for argv, said in ((["--fps", "1e-6"], "--fps must be between 0.1 and 100"),
                       (["--fps", "inf"], "--fps must be between"),
                       (["--pixels-per-metre", "100000"], "--pixels-per-metre must be between 1 and 400"),
                       (["--pixels-per-metre", "399"], "at most 4096 px a side")):
        started = time.monotonic()
        status, _, err = run_cli(capsys, "render", bag, "--out", tmp_path / "r.gif", *argv)
        assert status == 2, argv
        assert said in err and len(err.strip().splitlines()) == 1, err
        assert time.monotonic() - started < 5.0          # refused before anything is drawn
        assert not (tmp_path / "r.gif").exists()
    # the frames' memory is bounded too: with a 2 MB budget this game's 40 px/m frames need --stride
    monkeypatch.setattr(bag_inspect, "RENDER_MAX_FRAME_BYTES", 2_000_000)
    status, _, err = run_cli(capsys, "render", bag, "--out", tmp_path / "r.gif")
    assert status == 2 and "--stride" in err and "GiB" in err, err
    status, out, err = run_cli(capsys, "render", bag, "--out", tmp_path / "r.gif", "--stride", "20")
    assert status == 0, err
    assert bag_main(["render", str(bag), "--out", str(tmp_path / "ok.gif"), "--fps", "100", "--stride", "20"]) == 0
