"""The recorder under faults: an output directory it cannot write is one line of error; a disk that fills up while
recording is reported on /recorder/diagnostics at ERROR level and the part already written stays readable; the
parameters used only at start are read-only."""
from __future__ import annotations

import errno
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import pytest
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

from dynenv_ros.bags.inspect import bag_info, echo
from dynenv_ros.ros import topics
from dynenv_ros.ros.qos import sim_stream
from ros_harness import spin_until
from test_bags import simulated_messages

REPO = Path(__file__).resolve().parent.parent


@pytest.fixture(scope="module")
def worlds() -> list[object]:
    return [m for t, _, m, _ in simulated_messages(periods=4) if t == topics.WORLD_STATE]


def test_a_read_only_output_directory_is_one_line_of_error_and_exit_2():
    """The directory is made read-only (mode 0555) and, since root ignores modes, os.mkdir inside it fails the
    way a read-only mount does (EROFS)."""
    read_only = Path(tempfile.mkdtemp(prefix="dynenv-ro-"))
    read_only.chmod(0o555)
    script = ("import errno, os, sys\n"
              "real = os.mkdir\n"
              "def mkdir(path, *args, **kwargs):\n"
              f"    if str(path).startswith({str(read_only) + '/'!r}):\n"
              "        raise OSError(errno.EROFS, os.strerror(errno.EROFS), str(path))\n"
              "    return real(path, *args, **kwargs)\n"
              "os.mkdir = mkdir\n"
              "from dynenv_ros.nodes.recorder import cli_main\n"
              "raise SystemExit(cli_main(sys.argv[1:]))\n")
    try:
        done = subprocess.run([sys.executable, "-c", script, "--output", str(read_only / "bag")], cwd=REPO,
                              capture_output=True, text=True, timeout=60)
    finally:
        read_only.chmod(0o755)
        read_only.rmdir()
    assert done.returncode == 2, done.stderr
    assert "Traceback" not in done.stderr
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and "cannot create bag" in lines[0] and os.strerror(errno.EROFS) in lines[0], lines


class _FullDisk:
    """Stands in for the bag's file once the disk is full: the next write lands partly (as the kernel does),
    every write after that fails with ENOSPC."""

    def __init__(self, real) -> None:
        self.real = real
        self.calls = 0

    def write(self, data) -> int:
        self.calls += 1
        if self.calls == 1:
            return self.real.write(bytes(data)[:1000])
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    def __getattr__(self, name: str):
        return getattr(self.real, name)


def test_a_full_disk_is_reported_on_diagnostics_and_the_written_part_stays_readable(tmp_path, make_node, executor,
                                                                                     worlds):
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
    from dynenv_msgs.msg import WorldState
    from dynenv_ros.nodes.recorder import DIAGNOSTICS_TOPIC, Recorder

    source = make_node("fake_sim")
    publisher = source.create_publisher(WorldState, topics.WORLD_STATE, sim_stream())
    statuses: list = []
    source.create_subscription(DiagnosticArray, DIAGNOSTICS_TOPIC, lambda m: statuses.extend(m.status), QoSProfile(
        depth=10, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL))
    bag = tmp_path / "full"
    recorder = make_node(Recorder, exit_when_done=False,
                         parameter_overrides=[Parameter("output", Parameter.Type.STRING, str(bag))])
    for node in (source, recorder):
        executor.add_node(node)
    assert spin_until(executor, lambda: publisher.get_subscription_count() == 1, 10.0)
    before, during, after = worlds[:8], worlds[8:14], worlds[14:20]
    for message in before:
        publisher.publish(message)
    # a quiet recorder still hands its open chunk to the OS within a second (flush timer)
    recording = recorder.recording
    assert spin_until(executor, lambda: recording.bag.flushed_messages == len(before), 5.0), recorder.counts
    assert any(s.level == DiagnosticStatus.OK for s in statuses) or spin_until(
        executor, lambda: any(s.level == DiagnosticStatus.OK for s in statuses), 3.0)
    storage = recording.bag._storage
    storage._file = _FullDisk(storage._file)
    for message in during:
        publisher.publish(message)
    assert spin_until(executor, lambda: any(s.level == DiagnosticStatus.ERROR for s in statuses), 5.0), \
        [s.message for s in statuses]
    for message in after:
        publisher.publish(message)
    assert spin_until(executor, lambda: recording.dropped == len(during) + len(after), 5.0), recording.dropped
    error = next(s for s in statuses if s.level == DiagnosticStatus.ERROR)
    assert "not recording" in error.message and "disk full" in error.message
    assert {v.key: v.value for v in error.values}["messages_written"] == str(len(before))
    recorder.finish()
    assert recording.recovered == len(before)
    info = bag_info(bag)   # reindexed at the end: readable without --ignore-damage
    assert info["message_count"] == len(before)
    assert {t["name"]: t["count"] for t in info["topics"]} == {topics.WORLD_STATE: len(before)}


def test_the_recorder_reports_each_topic_s_matched_publishers(tmp_path, make_node, executor):
    """What a stepped simulator's wait_for_recorder reads (docs/ros_graph.md); published on each match, not only by
    the 1 s timer."""
    from diagnostic_msgs.msg import DiagnosticArray
    from dynenv_msgs.msg import Action
    from dynenv_ros.nodes.recorder import DIAGNOSTICS_TOPIC, Recorder

    recorder = make_node(Recorder, exit_when_done=False, parameter_overrides=[
        Parameter("output", Parameter.Type.STRING, str(tmp_path / "bag")),
        Parameter("topics", Parameter.Type.STRING_ARRAY, ["/team_a_0/action"])])
    reports: list[dict[str, str]] = []
    watcher = make_node("watcher")
    watcher.create_subscription(DiagnosticArray, DIAGNOSTICS_TOPIC, lambda m: reports.extend(
        {v.key: v.value for v in s.values} for s in m.status), QoSProfile(
        depth=10, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL))
    for node in (recorder, watcher):
        executor.add_node(node)
    policy = make_node("policy")
    policy.create_publisher(Action, "/team_a_0/action", sim_stream())
    executor.add_node(policy)
    key = "matched_publishers:/team_a_0/action"
    assert spin_until(executor, lambda: any(r.get(key) == "1" for r in reports), 10.0), reports[-1:]


def test_actions_sent_before_the_recorder_matched_the_policy_are_recorded(tmp_path, make_node, executor):
    """Discovery is asymmetric, and a short stepped game lost a policy's first actions to it: policies keep their
    last actions (transient local) and the recorder, adapting to what publishers offer, asks for them; a volatile
    publisher (a user's own policy) is still recorded, from when it matched."""
    from dynenv_msgs.msg import Action
    from dynenv_ros.nodes.recorder import Recorder
    from dynenv_ros.ros.qos import ACTION_HISTORY_DEPTH, action_stream

    policy = make_node("policy")
    kept = policy.create_publisher(Action, "/team_a_0/action", action_stream())
    plain = policy.create_publisher(Action, "/team_b_0/action", sim_stream())
    executor.add_node(policy)
    early = ACTION_HISTORY_DEPTH // 2
    for period in range(1, early + 1):                   # before any recorder exists
        kept.publish(Action(robot_id=0, episode_id=1, motion_period=period))
    bag = tmp_path / "bag"
    recorder = make_node(Recorder, exit_when_done=False, parameter_overrides=[
        Parameter("output", Parameter.Type.STRING, str(bag))])
    executor.add_node(recorder)
    assert spin_until(executor, lambda: {"/team_a_0/action", "/team_b_0/action"} <= set(recorder.subscribed)
                      and plain.get_subscription_count() == 1, 10.0)
    for period in range(early + 1, early + 4):
        kept.publish(Action(robot_id=0, episode_id=1, motion_period=period))
        plain.publish(Action(robot_id=1, episode_id=1, motion_period=period))
    assert spin_until(executor, lambda: recorder.counts.get("/team_a_0/action", 0) == early + 3
                      and recorder.counts.get("/team_b_0/action", 0) == 3, 10.0), recorder.counts
    recorder.finish()
    periods = [r["message"]["motion_period"] for r in echo(bag, "/team_a_0/action")]
    assert periods == list(range(1, early + 4))


@pytest.mark.parametrize("name, value", [("duration", Parameter("duration", Parameter.Type.DOUBLE, 5.0)),
                                         ("output", Parameter("output", Parameter.Type.STRING, "/tmp/elsewhere")),
                                         ("topics", Parameter("topics", Parameter.Type.STRING_ARRAY, ["/x"]))])
def test_parameters_used_only_at_start_are_read_only(tmp_path, make_node, name, value):
    from dynenv_ros.nodes.recorder import Recorder

    recorder = make_node(Recorder, exit_when_done=False,
                         parameter_overrides=[Parameter("output", Parameter.Type.STRING, str(tmp_path / "bag"))])
    before = recorder.get_parameter(name).value
    result = recorder.set_parameters([value])[0]
    assert not result.successful
    assert "read-only" in result.reason.lower() or "read only" in result.reason.lower(), result.reason
    assert recorder.get_parameter(name).value == before
    assert recorder.describe_parameter(name).read_only
