"""The trainer node's experience intake: finds every robot (car) of every game on the graph and subscribes to its
detections, actions and feedback, and to the game's ``world_state`` when the learner needs targets, handing each
message to the experience assembler (``learning.experience``, duck-typed here: ``names``, ``learns``,
``with_targets``, ``add_frame``, ``add_action``, ``add_feedback``, ``add_world_state``, ``take``).

A robot's topics are ``<game namespace>/<robot>/detections`` (type DetectionArray; the root namespace is a game
too), ``.../action`` and ``.../feedback``. With authenticated frames (``frames``: a ``ros.frame_tags.FrameReceiver``)
a frame or world state is added once its tag came. Every callback drains its topic's queue (``ros.drain``): the
executor takes one message per subscription per wake-up, so a robot's frames (five per period) would fall behind
its actions and feedback (one each) and miss their periods.
"""
from __future__ import annotations

import re
from collections import Counter
from collections.abc import Callable
from typing import Any

from dynenv_msgs.msg import Action, DetectionArray, StepFeedback, WorldState
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from dynenv_ros.ros.drain import take
from dynenv_ros.ros.frame_tags import FrameReceiver
from dynenv_ros.security.frame_auth import detection_array_bytes, world_state_bytes

DETECTION_TYPE = "dynenv_msgs/msg/DetectionArray"
# Keep-last depths of the experience readers: deep enough that a stepped game's burst (an episode's last period and
# the next one's first) and a learner holding the GIL for a moment lose nothing; bounded so a trainer that cannot
# keep up falls behind in its own memory, never the games' (a reliable keep-last reader never blocks a writer).
FRAME_DEPTH, MESSAGE_DEPTH = 400, 100


def detections_pattern(agent_pattern: str) -> re.Pattern[str]:
    """``<game namespace>/<agent>/detections`` for agents named by ``agent_pattern`` (the scenario's)."""
    return re.compile(rf"^(?P<source>(/[A-Za-z0-9_]+)*)/(?P<robot>{agent_pattern})/detections$")


def experience_qos(depth: int, latched: bool = False) -> QoSProfile:
    """Reliable keep-last. Actions are read transient local: a policy node keeps its last 20 (``qos.action_stream``),
    so the first answers of a game are not lost while the trainer's reader is still matching the policy's writer (a
    stepped game starts once the trainer reads the detections, not once it has matched every policy). A publisher
    offering only volatile durability does not match such a reader — its actions carry no learning fields anyway."""
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=depth, reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.TRANSIENT_LOCAL if latched else DurabilityPolicy.VOLATILE)


class ExperienceReaders:
    """The experience subscriptions of one trainer (module docstring); ``deliver``: what to do with the sequences
    the assembler completes (the learner's queue)."""

    def __init__(self, node: Node, assembler: Any, agent_pattern: str, frames: bytes | None,
                 deliver: Callable[[Any], None]) -> None:
        self.node, self.assembler, self.deliver = node, assembler, deliver
        self.detections = detections_pattern(agent_pattern)
        self.received: Counter[str] = Counter()
        self.robots: set[tuple[str, str]] = set()
        self.games: set[str] = set()
        self.subscriptions: list[Any] = []
        self.frame_gate = FrameReceiver(node, frames) if frames is not None else None

    def discover(self) -> None:
        """Subscribe to every robot that has appeared (names and types from the graph, no configuration)."""
        node = self.node
        for name, types in node.get_topic_names_and_types():
            match = self.detections.match(name)
            if match is None or DETECTION_TYPE not in types:
                continue
            source, robot = match["source"], match["robot"]
            if (source, robot) in self.robots or robot not in self.assembler.names:
                continue
            self.robots.add((source, robot))
            if not self.assembler.learns(robot):
                continue
            add = self.assembler
            for msg_type, topic, method, kind, depth, latched in (
                    (DetectionArray, name, self._gated(add.add_frame, name, detection_array_bytes), "frames",
                     FRAME_DEPTH, False),
                    (Action, f"{source}/{robot}/action", add.add_action, "actions", MESSAGE_DEPTH, True),
                    (StepFeedback, f"{source}/{robot}/feedback", add.add_feedback, "feedback", MESSAGE_DEPTH, False)):
                handler = self._handler(method, source, robot, kind, depth)
                handler.subscription = node.create_subscription(msg_type, topic, handler,
                                                                experience_qos(depth, latched))
                self.subscriptions.append(handler.subscription)
            if self.frame_gate is not None:
                self.subscriptions.append(self.frame_gate.subscribe(node.resolve_topic_name(name),
                                                                    experience_qos(FRAME_DEPTH), self._release))
            if source not in self.games:
                self.games.add(source)
                if add.with_targets:
                    world = f"{source}/world_state"
                    self.subscriptions.append(node.create_subscription(
                        WorldState, world, self._world_handler(source), experience_qos(FRAME_DEPTH)))
                    if self.frame_gate is not None:
                        self.subscriptions.append(self.frame_gate.subscribe(
                            node.resolve_topic_name(world), experience_qos(FRAME_DEPTH), self._release))
            node.get_logger().info(f"learning from {source or '/'} {robot}")

    def _handler(self, add: Callable[..., None], source: str, robot: str, kind: str, depth: int) -> Any:
        """The callback of one experience topic; it drains the topic's queue (module docstring)."""
        def receive(msg: Any) -> None:
            for _ in range(depth):
                self.received[kind] += 1
                try:
                    add(source, robot, msg)
                except Exception as error:     # a message nothing foresaw: dropped and counted, never fatal
                    self.received["errors"] += 1
                    self.node.get_logger().error(f"{kind} of {source}/{robot} dropped: {type(error).__name__}: "
                                                 f"{error}", throttle_duration_sec=5.0)
                msg = take(receive.subscription)    # type: ignore[attr-defined]
                if msg is None:
                    break
            ready = self.assembler.take()
            if ready:
                self.deliver(ready)
        receive.subscription = None                 # type: ignore[attr-defined]
        return receive

    def _world_handler(self, source: str) -> Callable[[Any], None]:
        add = self._gated(lambda _source, _robot, msg: self.assembler.add_world_state(source, msg),
                          f"{source}/world_state", world_state_bytes)

        def receive(msg: Any) -> None:
            self.received["world_states"] += 1
            add(source, None, msg)
        return receive

    def _gated(self, add: Callable[..., None], topic: str, encode: Callable[[Any, str], bytes]) -> Callable[..., None]:
        """``add`` as it is, or with authenticated frames behind the gate: a frame is added once its tag came
        (now, or later by ``_release``)."""
        gate = self.frame_gate
        if gate is None:
            return add
        topic = self.node.resolve_topic_name(topic)

        def admit(source: str, robot: str | None, msg: Any) -> None:
            try:
                data: bytes | None = encode(msg, topic)
            except ValueError:
                data = None
            for item in gate.frame((add, source, robot, msg), data, topic):
                self._add_verified([item])
        return admit

    def _release(self, items: list[Any]) -> None:
        """Frames whose tag came after them: added, and whatever they complete handed to the learner."""
        self._add_verified(items)
        ready = self.assembler.take()
        if ready:
            self.deliver(ready)

    def _add_verified(self, items: list[Any]) -> None:
        for add, source, robot, msg in items:
            try:
                add(source, robot, msg)
            except Exception as error:     # as the handlers: a message nothing foresaw is dropped and counted
                self.received["errors"] += 1
                self.node.get_logger().error(f"frame of {source}/{robot} dropped: {type(error).__name__}: {error}",
                                             throttle_duration_sec=5.0)


__all__ = ["ExperienceReaders", "detections_pattern", "experience_qos", "DETECTION_TYPE", "FRAME_DEPTH",
           "MESSAGE_DEPTH"]
