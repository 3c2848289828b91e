"""Recorder: subscribes (raw CDR, no deserialisation) to the simulator's topics and writes them to a rosbag2 MCAP
bag, because there is no ``ros2 bag`` on PyPI.

Parameters (read-only: they are used once, when the bag is created, so a later change is refused rather than
silently ignored):
  output    bag directory to create (default ``bags/recording_<UTC time>``); an existing path is refused.
  topics    topics to record; empty = every topic whose type the simulator publishes (``SIM_PUBLISHED_TYPES``)
            plus policies' ``dynenv_msgs/msg/Action``, except the recorder's own diagnostics and ``/diagnostics``
            (every node's statuses; the simulator's are recorded from its own topic). Either way topics
            are found by polling the ROS graph every 0.5 s, so a topic that appears later is recorded from then on.
  duration  seconds of wall time to record, 0 = until SIGINT/SIGTERM.

Crash safety: the bag is written in chunks of at most 256 KiB / 0.5 s, each handed to the OS when it closes (and
every FLUSH_PERIOD_S the open one if it is old enough), so after kill -9 ``dynenv-bag reindex`` recovers all but
the last ~0.75 s. A bag that cannot be created (read-only or missing permissions, disk full) is one line of error
and exit status 2. A write that fails while recording (disk full, I/O error) stops the recording: one error line,
the messages that follow are counted as dropped, and /recorder/diagnostics (``DIAGNOSTICS_TOPIC``,
diagnostic_msgs/DiagnosticArray, reliable + transient-local depth 1, about 1 Hz) says ERROR "not recording" so the
simulator and the graph can see it; at the end the recorder reindexes what reached the disk and exits 1.
While recording, the same topic says OK with the counts.

Bag time (``bags/recording.py``, the bag's ROS-free part): a message's receive time, wall or with
``use_sim_time:=true`` the latest /clock recorded; the sim time stays in its header.stamp. Subscriptions are
KEEP_ALL, reliable and transient local when every publisher of the topic offers it (as rosbag2 adapts them), so a
recorder that falls behind holds a reliable publisher back instead of silently losing messages (once the writer's
history is full, the publisher's publish() fails after Fast DDS's blocking time rather than dropping), and latched
messages (/tf_static) are received however late the recorder starts. Each topic's metadata records the profile every
publisher discovered on it offers (``offered_qos_profiles``, rosbag2 version 9), which the player republishes with.
The bag is finished (MCAP footer, metadata.yaml) on every exit path and a summary (messages per topic) is logged.
SIGINT/SIGTERM first drain what is already on its way (until no message arrived for DRAIN_QUIET_S, at most
DRAIN_MAX_S), then finish the bag and exit 0; a second signal finishes at once.

``dynenv-record --output DIR --topics T ... --duration S`` (``cli_main``) is the same node with argparse options.
"""
from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Sequence
from datetime import datetime, timezone
from typing import Any

from rclpy.clock import Clock, ClockType
from rclpy.event_handler import SubscriptionEventCallbacks
from rclpy.exceptions import ParameterException
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

from dynenv_ros.bags.mcap import CHUNK_MAX_AGE_S, FLUSH_PERIOD_S
from dynenv_ros.bags.recording import Recording
from dynenv_ros.ros.bag_qos import bag_qos, describe
from dynenv_ros.ros.diagnostics import STANDARD_TOPIC as STANDARD_DIAGNOSTICS, Diagnostics
from dynenv_ros.ros.message_classes import message_class
from dynenv_ros.ros.node_runner import NodeExit
from dynenv_ros.ros.parameters import declare_float, declare_str, declare_str_list
from dynenv_ros.ros.qos import recording_qos
from dynenv_ros.ros.signal_runner import run_draining
from dynenv_ros.ros.topics import MATCHED_PREFIX, RECORDER_DIAGNOSTICS, SIM_PUBLISHED_TYPES, local

# The simulator's topics, the policies' actions and the vision adapter's standard detections.
RECORDED_TYPES = frozenset(SIM_PUBLISHED_TYPES | {"dynenv_msgs/msg/Action", "vision_msgs/msg/Detection3DArray"})
DISCOVERY_PERIOD_S = 0.5
DRAIN_QUIET_S = 0.25      # after a stop request, finish once no message arrived for this long ...
DRAIN_MAX_S = 2.0         # ... or after this long at most (a publisher that keeps publishing)
DIAGNOSTICS_TOPIC = RECORDER_DIAGNOSTICS
DIAGNOSTICS_PERIOD_S = 1.0


def default_output() -> str:
    return f"bags/recording_{datetime.now(timezone.utc).strftime('%Y%m%dT%H%M%SZ')}"


class Recorder(Node):
    def __init__(self, *, exit_when_done: bool = True, **node_options: Any) -> None:
        """``exit_when_done``: raise NodeExit when ``duration`` elapses (False in in-process tests, which watch
        ``finished``). ``node_options`` go to rclpy's Node (context, parameter_overrides, ...)."""
        super().__init__("recorder", **node_options)
        # Timers run on the steady clock: with use_sim_time the node clock stands still until /clock arrives.
        self._wall = Clock(clock_type=ClockType.STEADY_TIME)
        self.output = declare_str(self, "output", default_output(), "Bag directory to create (must not exist).",
                                  read_only=True)
        requested = declare_str_list(self, "topics", [], "Topics to record; empty = every simulator topic.",
                                     read_only=True)
        self.duration = declare_float(self, "duration", 0.0, 0.0, 1e9, "Wall seconds to record, 0 = until stopped.",
                                      read_only=True)
        self.requested = {self.resolve_topic_name(t) for t in requested}
        self.exit_when_done = exit_when_done
        self.finished = False
        self._subscriptions: list[Any] = []
        try:
            # With use_sim_time the bag time is the latest /clock value this node recorded (bags/recording.py).
            self.recording = Recording(self.output, bool(self.get_parameter("use_sim_time").value))
        except FileExistsError as error:
            raise ParameterException(str(error), ["output"]) from None
        except OSError as error:   # read-only or foreign directory, disk full: one line, exit 2
            print(f"recorder: error: cannot create bag {self.output!r}: {error.strerror or error}",
                  file=sys.stderr, flush=True)
            raise NodeExit(2) from None

        self._diagnostics = Diagnostics(self, local(DIAGNOSTICS_TOPIC), QoSProfile(   # and /diagnostics
            depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL))
        self.subscribed: dict[str, str] = {}          # topic → type
        self._ignored: set[tuple[str, tuple[str, ...]]] = set()   # warned about once
        self._started = time.monotonic()
        self._last_message = self._started
        self._stop_requested: float | None = None
        self._discover()
        self._discovery_timer = self.create_timer(DISCOVERY_PERIOD_S, self._discover, clock=self._wall)
        self._stop_timer = self.create_timer(0.05, self._check_stop, clock=self._wall)
        self._flush_timer = self.create_timer(FLUSH_PERIOD_S, self._flush, clock=self._wall)
        self._diagnostics_timer = self.create_timer(DIAGNOSTICS_PERIOD_S, self.publish_diagnostics, clock=self._wall)
        what = ", ".join(sorted(self.requested)) if self.requested else "all simulator topics"
        self.get_logger().info(f"recording {what} to {self.output}"
                               + (f" for {self.duration:g} s" if self.duration > 0 else " until stopped"))

    @property
    def counts(self) -> dict[str, int]:
        """Messages written per topic so far."""
        return self.recording.counts

    @property
    def failure(self) -> str:
        """Why nothing is being recorded any more ("" while recording)."""
        return self.recording.failure

    def _wanted(self, topic: str, types: list[str]) -> bool:
        if self.requested:
            return topic in self.requested
        # not its own diagnostics, nor /diagnostics (every node's, the simulator's again among them: its own
        # topic is recorded); --topics /diagnostics records it
        return (not topic.endswith(DIAGNOSTICS_TOPIC) and topic != STANDARD_DIAGNOSTICS
                and any(t in RECORDED_TYPES for t in types))

    def _discover(self) -> None:
        if self.finished or self.failure:
            return
        for topic, types in self.get_topic_names_and_types():
            if self.failure:
                return
            if topic in self.subscribed or not self._wanted(topic, types):
                continue
            # As rosbag2: a topic is subscribed once it has a publisher, with QoS adapted to what they offer, and
            # the bag records each publisher's offered profile (the player republishes with them).
            offered = [info.qos_profile for info in self.get_publishers_info_by_topic(topic)]
            if not offered:
                continue
            key = (topic, tuple(types))
            if key in self._ignored:
                continue
            reason = self._subscribe(topic, types, offered)
            if reason:
                self._ignored.add(key)
                self.get_logger().warning(f"not recording {topic}: {reason}")

    def _subscribe(self, topic: str, types: list[str], offered: list[QoSProfile]) -> str:
        """Start recording ``topic`` from publishers offering ``offered``; returns why not, or "" on success."""
        if len(types) != 1:
            return f"it has several types {types}"
        msgtype = types[0]
        qos = recording_qos(offered)
        for policy in ("reliability", "durability"):
            kinds = {getattr(p, policy) for p in offered}
            if len(kinds) > 1:   # as rosbag2 warns: the weaker request matches all, the stronger offers lose
                self.get_logger().warning(
                    f"{topic}: publishers differ in {policy} ({', '.join(sorted(k.name.lower() for k in kinds))});"
                    f" recording {getattr(qos, policy).name.lower()}, which matches them all")
        try:
            cls = message_class(msgtype)
            self.recording.bag.add_topic(topic, msgtype, [bag_qos(p) for p in offered])
        except (ImportError, ValueError, KeyError) as error:
            return str(error)
        except OSError as error:   # its definition could not be written: the bag is full or broken
            self._failed(error)
            return self.failure
        # A change in matched publishers is published at once: a stepped simulator waits for the recorder to have
        # matched every action publisher before its first period (MATCHED_PREFIX values of the diagnostics).
        self._subscriptions.append(self.create_subscription(
            cls, topic, lambda data, name=topic: self._on_message(name, data), qos, raw=True,
            event_callbacks=SubscriptionEventCallbacks(
                matched=lambda _info: self.publish_diagnostics(),
                incompatible_qos=lambda _info, name=topic: self.get_logger().warning(
                    f"{name}: a publisher's QoS does not match this recording's ({describe(qos)}); its messages "
                    "are not recorded", throttle_duration_sec=5.0))))
        self.subscribed[topic] = msgtype
        self.get_logger().info(f"recording {topic} [{msgtype}] ({describe(qos)})")
        return ""

    def _on_message(self, topic: str, data: bytes) -> None:
        self._last_message = time.monotonic()
        try:
            self.recording.write(topic, data)
        except OSError as error:
            self._failed(error, this_message=1)

    def _flush(self) -> None:
        """Hand a quiet topic's open chunk to the OS once it is CHUNK_MAX_AGE_S old (busy ones close by size)."""
        if self.failure or self.recording.bag.closed:
            return
        try:
            self.recording.bag.flush(max_age_s=CHUNK_MAX_AGE_S)
        except OSError as error:
            self._failed(error)

    def _failed(self, error: OSError, this_message: int = 0) -> None:
        """A write failed: stop recording (the file now ends in a partial record), say so once, tell the graph."""
        self.get_logger().error(self.recording.fail(error, this_message))
        self.publish_diagnostics()

    def publish_diagnostics(self) -> None:
        """OK with the counts while recording, ERROR "not recording: <why>" after a write failed."""
        from builtin_interfaces.msg import Time
        from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
        from std_msgs.msg import Header

        if not self.context.ok():
            return
        written = self.recording.written
        status = DiagnosticStatus(
            level=DiagnosticStatus.ERROR if self.failure else DiagnosticStatus.OK, name="recorder",
            message=f"not recording: {self.failure}" if self.failure else f"recording {len(self.subscribed)} topics",
            hardware_id=self.output,
            values=[KeyValue(key="output", value=self.output), KeyValue(key="messages_written", value=str(written)),
                    KeyValue(key="messages_dropped", value=str(self.recording.dropped))]
            + [KeyValue(key=MATCHED_PREFIX + s.topic_name, value=str(s.get_publisher_count()))
               for s in self._subscriptions])
        now = time.time_ns()
        header = Header(stamp=Time(sec=now // 1_000_000_000, nanosec=now % 1_000_000_000))
        self._diagnostics.publish(DiagnosticArray(header=header, status=[status]))

    def request_stop(self, drain: bool = True) -> None:
        """Stop soon (what SIGINT/SIGTERM do): with ``drain``, first keep taking the messages that are already on
        their way (a publisher that just finished has handed them to DDS, but they still sit in this node's queue);
        without, at the next timer tick."""
        now = time.monotonic()
        if self._stop_requested is None or not drain:
            self._stop_requested = now if drain else now - DRAIN_MAX_S

    def _check_stop(self) -> None:
        if self.finished:
            return
        now = time.monotonic()
        if self._stop_requested is not None:
            quiet = now - max(self._last_message, self._stop_requested) >= DRAIN_QUIET_S
            if not (quiet or now - self._stop_requested >= DRAIN_MAX_S):
                return
        elif not (self.duration > 0 and now - self._started >= self.duration):
            return
        self.finish()
        if self.exit_when_done:
            raise NodeExit(1 if self.failure else 0)

    def finish(self) -> None:
        """Stop recording, finish the bag so it is readable, and log what was recorded. Idempotent."""
        if self.finished:
            return
        self.finished = True
        for subscription in self._subscriptions:
            self.destroy_subscription(subscription)
        self._subscriptions.clear()
        summary = self.recording.close()
        if self.context.ok():
            (self.get_logger().error if self.failure else self.get_logger().info)(summary)
        else:   # after SIGINT/SIGTERM the logger's /rosout publisher is gone and would complain
            print(f"[recorder] {summary}", file=sys.stderr, flush=True)

    def destroy_node(self) -> None:
        if hasattr(self, "recording"):   # the constructor may have failed before the bag existed
            self.finish()
        super().destroy_node()


def main(args: Sequence[str] | None = None) -> int:
    return run_draining(Recorder, args)


def cli_main(argv: Sequence[str] | None = None) -> int:
    """``dynenv-record``: options instead of ROS parameters; arguments after ``--ros-args`` go to rclpy."""
    argv = list(sys.argv[1:] if argv is None else argv)
    ros_args = argv[argv.index("--ros-args"):] if "--ros-args" in argv else []
    own = argv[:len(argv) - len(ros_args)]
    parser = argparse.ArgumentParser(prog="dynenv-record", description="Record simulator topics to a rosbag2 "
                                     "MCAP bag (Ctrl-C finishes the bag).")
    parser.add_argument("--output", default=None, help="bag directory to create (default bags/recording_<UTC>)")
    parser.add_argument("--topics", nargs="*", default=None, help="topics to record (default: all simulator topics)")
    parser.add_argument("--duration", type=float, default=None, help="seconds of wall time (default: until Ctrl-C)")
    options = parser.parse_args(own)
    overrides = []
    if options.output is not None:
        overrides.append(Parameter("output", Parameter.Type.STRING, options.output))
    if options.topics:
        overrides.append(Parameter("topics", Parameter.Type.STRING_ARRAY, list(options.topics)))
    if options.duration is not None:
        overrides.append(Parameter("duration", Parameter.Type.DOUBLE, float(options.duration)))
    return run_draining(lambda: Recorder(parameter_overrides=overrides), [sys.argv[0], *ros_args])


if __name__ == "__main__":
    raise SystemExit(main())
