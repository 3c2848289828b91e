"""Every node's diagnostics on ``/diagnostics``, the topic ``diagnostic_aggregator``, ``rqt_robot_monitor`` and
Foxglove's diagnostics panel read (REP 107's convention), as well as on the node's own topic where it has one
(``/sim/diagnostics``, ``~/diagnostics``, …: the project's tools and the simulator's recorder watch read those).

On ``/diagnostics`` each status is named ``<fully qualified node name>: <status name>``, so the statuses of
several games (namespaces) and of nodes of one kind stay apart on the one shared topic. ``Heartbeat`` gives a node
with nothing more to say (a scripted policy, the bag player) an OK status once a second, with its counts.
"""
from __future__ import annotations

from collections.abc import Callable, Mapping

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.qos import QoSProfile

STANDARD_TOPIC = "/diagnostics"
HEARTBEAT_PERIOD_S = 1.0


class Diagnostics:
    """A node's diagnostics publisher(s): ``publish`` sends a DiagnosticArray to ``/diagnostics`` (names
    qualified) and, with ``own_topic``, unchanged to the node's own topic (with ``own_qos``, e.g. latched)."""

    def __init__(self, node: Node, own_topic: str | None = None, own_qos: QoSProfile | None = None) -> None:
        self.node = node
        self.standard = node.create_publisher(DiagnosticArray, STANDARD_TOPIC, QoSProfile(depth=10))
        self.own = (node.create_publisher(DiagnosticArray, own_topic, own_qos or QoSProfile(depth=10))
                    if own_topic else None)

    def publish(self, msg: DiagnosticArray) -> None:
        if msg.header.stamp.sec == 0 and msg.header.stamp.nanosec == 0:
            msg.header.stamp = self.node.get_clock().now().to_msg()
        if self.own is not None:
            self.own.publish(msg)
        prefix = self.node.get_fully_qualified_name()
        self.standard.publish(DiagnosticArray(header=msg.header, status=[
            DiagnosticStatus(level=s.level, name=s.name if s.name.startswith(prefix) else f"{prefix}: {s.name}",
                             message=s.message, hardware_id=s.hardware_id or prefix, values=list(s.values))
            for s in msg.status]))


class Heartbeat:
    """An OK status named ``name`` on ``/diagnostics`` every second of wall time, with ``values()``."""

    def __init__(self, node: Node, name: str, values: Callable[[], Mapping[str, object]],
                 message: Callable[[], str] = lambda: "running") -> None:
        self.diagnostics = Diagnostics(node)
        self.name, self.values, self.message = name, values, message
        self.timer = node.create_timer(HEARTBEAT_PERIOD_S, self.publish, clock=Clock(clock_type=ClockType.STEADY_TIME))
        self.publish()      # at once too: a short-lived node (the selfcheck listener) reports before it ends

    def publish(self) -> None:
        status = DiagnosticStatus(level=DiagnosticStatus.OK, name=self.name, message=self.message(),
                                  values=[KeyValue(key=k, value=str(v)) for k, v in self.values().items()])
        self.diagnostics.publish(DiagnosticArray(status=[status]))


__all__ = ["Diagnostics", "Heartbeat", "STANDARD_TOPIC"]
