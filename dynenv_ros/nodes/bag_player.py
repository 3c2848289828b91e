"""Bag player: republishes a rosbag2 bag's messages (raw CDR, never deserialised) on their original topics with
their original types, because there is no ``ros2 bag play`` on PyPI.

Parameters:
  bag                   bag directory (or the .mcap inside it).
  rate                  1.0 = the bag's own timing (its receive timestamps), 2.0 = twice as fast, 0 = as fast as
                        possible.
  loop                  start over at the end (until stopped).
  topics                topics to play; empty = all.
  wait_for_subscribers  before playing, wait until every played topic has at least this many subscribers
                        (0 = start at once, like ``ros2 bag play``; the simulator's topics are volatile, so
                        messages published before a subscriber matched are not delivered to it).
  ignore_damage         play a damaged or unfinished bag anyway: the messages that check out (see
                        ``dynenv-bag --ignore-damage``); default: refuse it (exit 2) with what is wrong.

A topic whose type is not installed here (no generated Python class) or whose definition in the bag cannot be
used is skipped with a warning naming it; the rest plays.

Each topic is republished with the QoS its recorded publishers offered (``offered_qos_profiles`` in the bag's
metadata, ``bags.qos.playback_qos``): the same reliability, durability, deadline, lifespan and liveliness, so every
reader they matched matches the player; transient-local topics (/tf_static, latched topics) keep their played
messages for readers that join later (a late RViz or tf2 listener gets the static frames), volatile ones are
KEEP_ALL so a slow reader slows playback instead of losing messages. A topic whose metadata holds no usable profile
(bags recorded before issue 28, or written without QoS) plays reliable, volatile, KEEP_ALL as before — but
``tf_static`` always plays transient local, as tf2 requires. ``qos_by_topic`` holds each topic's profile (logged
for the non-default ones). When not looping the node waits for every message to be acknowledged by the subscribers
(at most ACK_TIMEOUT_S) and exits 0; latched messages are served only while the player runs.

A topic recorded with an older definition of its type than the installed one (the RIHS01 hash the bag embeds
differs, e.g. a DetectionArray from before ``self_kicking`` and the GameController fields) cannot be republished
raw: its bytes would be misread. Its messages are decoded with the bag's definition and rebuilt as the installed
type, field by field; fields the old definition lacks keep their defaults (logged once per topic).
"""
from __future__ import annotations

import time
from collections.abc import Iterator, Sequence
from contextlib import ExitStack
from typing import Any

from rclpy.duration import Duration
from rclpy.exceptions import ParameterException
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.qos import QoSProfile
from rclpy.serialization import serialize_message
from rosidl_parser.definition import AbstractNestedType, NamespacedType

from dynenv_ros.bags.inspect import BagError, BagReader, open_bag
from dynenv_ros.bags.qos import playback_qos
from dynenv_ros.bags.typestore import dynenv_typestore
from dynenv_ros.ros.bag_qos import describe, ros_qos
from dynenv_ros.ros.diagnostics import Heartbeat
from dynenv_ros.ros.message_classes import message_class
from dynenv_ros.ros.node_runner import NodeExit
from dynenv_ros.ros.parameters import declare_bool, declare_float, declare_int, declare_str, declare_str_list
from dynenv_ros.ros.qos import sim_stream
from dynenv_ros.ros.signal_runner import RCLError, run_until_signal

TICK_S = 0.002            # playback timer period: the timing resolution at rate > 0
BATCH = 200               # messages per timer callback at most, so other callbacks of the executor still run
ACK_TIMEOUT_S = 10.0


class BagPlayer(Node):
    def __init__(self, *, exit_when_done: bool = True, **node_options: Any) -> None:
        """``exit_when_done``: raise NodeExit(0) after the last message (False in in-process tests, which watch
        ``finished``). ``node_options`` go to rclpy's Node (context, parameter_overrides, ...)."""
        super().__init__("bag_player", **node_options)
        # Timers run on the steady clock: with use_sim_time the node clock stands still until /clock arrives.
        self._wall = Clock(clock_type=ClockType.STEADY_TIME)
        self.bag_path = declare_str(self, "bag", "", "Bag directory to play.")
        self.rate = declare_float(self, "rate", 1.0, 0.0, 1000.0, "Playback speed factor, 0 = as fast as possible.")
        self.loop = declare_bool(self, "loop", False, "Start over at the end of the bag.")
        requested = declare_str_list(self, "topics", [], "Topics to play; empty = all.")
        self.wait_for_subscribers = declare_int(self, "wait_for_subscribers", 0, 0, 10_000,
                                                "Subscribers every topic must have before playing starts.")
        self.ignore_damage = declare_bool(self, "ignore_damage", False,
                                          "Play the messages of a damaged or unfinished bag that check out.")
        self.skipped: dict[str, str] = {}             # topic → why it is not played
        self.exit_when_done = exit_when_done
        self._stack = ExitStack()
        try:
            self._open(requested)
        except BaseException:
            self._stack.close()   # a refused start must not leave the bag open
            raise
        self.published: dict[str, int] = {topic: 0 for topic in self.publishers_by_topic}
        self.finished = False
        self.stalls = 0                                  # publishes refused by a full writer history, retried
        self._messages: Iterator[tuple[Any, int, bytes]] | None = None
        self._next: tuple[Any, int, bytes] | None = None
        self._origin: tuple[float, int] | None = None   # (monotonic start, first bag timestamp) of this pass
        self._waiting_since = time.monotonic()
        self._timer = self.create_timer(TICK_S, self._play, clock=self._wall)
        self.heartbeat = Heartbeat(self, "bag player", lambda: {
            "bag": str(self.bag_path), "messages_published": sum(self.published.values()), "stalls": self.stalls,
            "finished": self.finished}, lambda: "finished" if self.finished else "playing")
        self.get_logger().info(f"playing {self.bag_path}: {len(self.publishers_by_topic)} topics at "
                               + (f"rate {self.rate:g}" if self.rate > 0 else "full speed")
                               + (", looping" if self.loop else ""))

    def _open(self, requested: list[str]) -> None:
        """Open the bag and create one publisher per played topic; bad parameters raise ParameterException."""
        try:
            if not self.bag_path:
                raise BagError("no bag given (set the 'bag' parameter)")
            self.reader: BagReader = self._stack.enter_context(open_bag(
                self.bag_path, ignore_damage=self.ignore_damage, notice=self.get_logger().warning))
        except BagError as error:
            raise ParameterException(str(error), ["bag"]) from None
        wanted = {self.resolve_topic_name(t) for t in requested}
        in_bag = sorted({c.topic for c in self.reader.all_connections})
        self.skipped.update({t: why for t, why in self.reader.unreadable.items() if not wanted or t in wanted})
        candidates = [c for c in self.reader.connections if not wanted or c.topic in wanted]
        self.connections = []
        for connection in candidates:
            try:
                message_class(connection.msgtype)
            except (ImportError, ValueError) as error:
                if connection.topic not in self.skipped:
                    self.get_logger().warning(f"skipping {connection.topic}: {error}")
                self.skipped[connection.topic] = str(error)
                continue
            self.connections.append(connection)
        if not self.connections:
            if not wanted or set(wanted) & set(in_bag):
                raise ParameterException(f"nothing to play: every topic asked for is skipped ({self.skipped})",
                                         ["bag"])
            raise ParameterException(f"nothing to play: topics {sorted(wanted)} not in the bag (it has {in_bag})",
                                     ["topics"])
        self.publishers_by_topic: dict[str, Any] = {}
        self.qos_by_topic: dict[str, QoSProfile] = {}   # what each topic is republished with
        self.converted: dict[str, type] = {}            # topics recorded with an older definition: rebuilt
        store = dynenv_typestore()
        for connection in self.connections:
            if connection.topic not in self.publishers_by_topic:
                qos = self._playback_qos(connection.topic)
                self.qos_by_topic[connection.topic] = qos
                self.publishers_by_topic[connection.topic] = self.create_publisher(
                    message_class(connection.msgtype), connection.topic, qos)
                if describe(qos) != describe(sim_stream()):
                    self.get_logger().info(f"{connection.topic}: {describe(qos)}")
            digest = getattr(connection, "digest", "")
            if (connection.msgtype in store.fielddefs and digest.startswith("RIHS01_")
                    and digest != store.hash_rihs01(connection.msgtype)):
                self.converted[connection.topic] = message_class(connection.msgtype)
        for topic, cls in self.converted.items():
            self.get_logger().warning(f"{topic} was recorded with an older definition of {cls.__name__}: its "
                                      "messages are rebuilt as the installed type; fields the bag lacks keep "
                                      "their defaults")

    def _playback_qos(self, topic: str) -> QoSProfile:
        """The topic's recorded offers (every connection of it in the bag) → the profile to publish with."""
        connections = [c for c in self.connections if c.topic == topic]
        offered = [q for c in connections for q in getattr(c.ext, "offered_qos_profiles", None) or []]
        return ros_qos(playback_qos(topic, offered, sum(c.msgcount for c in connections)))

    def _subscribers_ready(self) -> bool:
        if self.wait_for_subscribers == 0:
            return True
        ready = all(p.get_subscription_count() >= self.wait_for_subscribers
                    for p in self.publishers_by_topic.values())
        if not ready and time.monotonic() - self._waiting_since > 5.0:
            self._waiting_since = time.monotonic()
            self.get_logger().info(f"waiting for {self.wait_for_subscribers} subscriber(s) on every topic")
        return ready

    def _fetch(self) -> tuple[Any, int, bytes] | None:
        """The next message to publish, starting a new pass when looping; None at the end."""
        if self._next is not None:
            return self._next
        for attempt in range(2):
            if self._messages is None:
                self._messages = self.reader.messages(self.connections)
                self._origin = None
            self._next = next(self._messages, None)
            if self._next is not None:
                if self._origin is None:
                    self._origin = (time.monotonic(), self._next[1])
                return self._next
            self._messages = None
            if not self.loop or attempt == 1:   # an empty pass would loop forever doing nothing
                return None
        return None

    def _play(self) -> None:
        if self.finished or (self._messages is None and self._next is None and not self._subscribers_ready()):
            return
        now = time.monotonic()
        for _ in range(BATCH):
            if not self.context.ok():   # SIGINT/SIGTERM arrived during this callback: stop publishing
                return
            try:
                item = self._fetch()
            except BagError as error:   # a damaged chunk: stop with the reason rather than a traceback
                self.get_logger().error(str(error))
                self._finish(status=2)
                return
            if item is None:
                self._finish(status=0)
                return
            connection, timestamp, raw = item
            if self.rate > 0 and self._origin is not None:
                due = self._origin[0] + (timestamp - self._origin[1]) / 1e9 / self.rate
                if due > now:
                    return
            target = self.converted.get(connection.topic)
            if target is not None:
                try:
                    message = self.reader.deserialize(raw, connection.msgtype)
                except BagError as error:
                    self.get_logger().error(str(error))
                    self._finish(status=2)
                    return
                raw = serialize_message(to_installed(message, target))
            try:
                self.publishers_by_topic[connection.topic].publish(bytes(raw))
            except RCLError as error:
                if not self.context.ok():
                    return
                # KEEP_ALL reliable (volatile topics): a subscriber that does not keep up fills the writer's history
                # and publish fails after the middleware's blocking time. Keep the message and retry on the next tick.
                self.stalls += 1
                self.get_logger().warning(f"publishing on {connection.topic} stalled ({error}); retrying",
                                          throttle_duration_sec=5.0)
                return
            self.published[connection.topic] += 1
            self._next = None

    def _finish(self, status: int) -> None:
        self.finished = True
        self._timer.cancel()
        for publisher in self.publishers_by_topic.values():   # deliver before the process ends
            publisher.wait_for_all_acked(Duration(seconds=ACK_TIMEOUT_S))
        lines = "\n".join(f"  {topic}: {count}" for topic, count in sorted(self.published.items()))
        stalled = f" ({self.stalls} stalled publishes retried)" if self.stalls else ""
        self.get_logger().info(f"played {sum(self.published.values())} messages{stalled}\n{lines}")
        if self.exit_when_done:
            raise NodeExit(status)

    def destroy_node(self) -> None:
        if hasattr(self, "_stack"):
            self._stack.close()
        super().destroy_node()


def to_installed(value: Any, cls: type) -> Any:
    """A message decoded by rosbags with a bag's own (older) definition → an instance of the installed class
    ``cls``: fields of the same name copied, nested messages and sequences of them recursively; fields the old
    definition lacks keep their defaults."""
    msg = cls()
    for name, kind in zip(cls.get_fields_and_field_types(), cls.SLOT_TYPES):
        if not hasattr(value, name):
            continue
        old = getattr(value, name)
        if isinstance(kind, NamespacedType):
            old = to_installed(old, message_class("/".join((*kind.namespaces, kind.name))))
        elif isinstance(kind, AbstractNestedType) and isinstance(kind.value_type, NamespacedType):
            item = message_class("/".join((*kind.value_type.namespaces, kind.value_type.name)))
            old = [to_installed(v, item) for v in old]
        elif hasattr(old, "tolist"):      # numpy arrays and scalars → Python values the generated setters accept
            old = old.tolist()
        setattr(msg, name, old)
    return msg


def main(args: Sequence[str] | None = None) -> int:
    return run_until_signal(BagPlayer, args)


if __name__ == "__main__":
    raise SystemExit(main())
