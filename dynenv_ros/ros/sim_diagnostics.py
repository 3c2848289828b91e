"""The simulator's diagnostics (``/diagnostics`` and ``/sim/diagnostics``, status ``dynenv_sim``) and its log's
periodic line, and what it hears from the recorder.

A recorder that stopped writing (disk full, I/O error) says so on its latched diagnostics; the simulator repeats it
in its own diagnostics and log, where an operator watching the game looks. A dynenv recorder also says which action
publishers it has matched, which ``wait_for_recorder`` waits for (``sim_graph``).
"""
from __future__ import annotations

from collections.abc import Mapping

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.node import Node

from dynenv_ros.envs.action_gate import ActionGate
from dynenv_ros.ros import topics
from dynenv_ros.ros.diagnostics import Diagnostics
from dynenv_ros.ros.qos import latched
from dynenv_ros.ros.topics import local


class SimDiagnostics:
    """Publishes the game's diagnostics values and logs them (one line in ten, or any trouble), with the gate's
    summary of refused actions; listens to the recorder's diagnostics."""

    def __init__(self, node: Node, gate: ActionGate) -> None:
        self.node, self.gate = node, gate
        self.publisher = Diagnostics(node, local(topics.DIAGNOSTICS))     # and /diagnostics
        self.sent = 0
        self.recorder_error = ""
        self.recorder_matched: dict[str, int] = {}      # topic -> publishers the recorder has matched
        self.recorder_sub = node.create_subscription(DiagnosticArray, local(topics.RECORDER_DIAGNOSTICS),
                                                     self._on_recorder_diagnostics, latched(1))

    def _on_recorder_diagnostics(self, msg: DiagnosticArray) -> None:
        for status in msg.status:
            for value in status.values:
                if value.key.startswith(topics.MATCHED_PREFIX) and value.value.isdigit():
                    self.recorder_matched[value.key[len(topics.MATCHED_PREFIX):]] = int(value.value)
        errors = [s.message or "error" for s in msg.status if s.level == DiagnosticStatus.ERROR]
        error = "; ".join(errors)
        if error and error != self.recorder_error:
            self.node.get_logger().error(f"recorder: {error}")
        elif not error and self.recorder_error:
            self.node.get_logger().info("recorder: recording again")
        self.recorder_error = error

    def publish(self, values: Mapping[str, str]) -> None:
        problems = sum(int(v) for k, v in values.items() if k.startswith("rejected_"))
        if self.recorder_error:
            level, message = DiagnosticStatus.ERROR, f"recorder: {self.recorder_error}"
        elif problems:
            level, message = DiagnosticStatus.WARN, f"{problems} actions rejected"
        else:
            level, message = DiagnosticStatus.OK, "ok"
        status = DiagnosticStatus(level=level, name="dynenv_sim", message=message, hardware_id="simulation",
                                  values=[KeyValue(key=k, value=v) for k, v in values.items()])
        msg = DiagnosticArray(status=[status])
        msg.header.stamp = self.node.get_clock().now().to_msg()
        self.publisher.publish(msg)
        self.sent += 1
        logger = self.node.get_logger()
        refusals = self.gate.refusal_summary()
        if refusals:
            logger.warning(refusals)
        line = " ".join(f"{k}={v}" for k, v in values.items() if v not in ("0", "0.00"))
        if problems or self.sent % 10 == 1:     # the log gets one line in ten, or any trouble
            logger.info(line)


__all__ = ["SimDiagnostics"]
