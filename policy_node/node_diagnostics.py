"""The policy node's ``~/diagnostics`` (and ``/diagnostics``): counts since start and the decision latency of the
last window, as DiagnosticStatus strings, every ``diagnostics_period`` of steady time; WARN with the counts that grew
when trouble is new (dropped periods, missing, malformed or duplicate frames, fallback actions, refused weights or
pose estimates), and one log line in ten, or any new trouble. A mixin of ``PolicyNode``: it reads the node's state.
"""
from __future__ import annotations

import statistics

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue

COUNTED = ("decisions", "periods_dropped", "actions_delayed", "actions_superseded", "frames_received",
           "frames_stale", "frames_duplicate", "periods_partial", "frames_missing", "frames_malformed",
           "detections_malformed", "values_malformed", "self_missing", "fallback_actions",
           "failed_decisions", "weights_loaded", "weights_refused", "weights_duplicate", "weights_other_run",
           "pose_used", "pose_missing", "pose_stale", "pose_late", "pose_malformed")
WATCHED = ("periods_dropped", "frames_duplicate", "frames_missing", "frames_malformed",
           "detections_malformed", "values_malformed", "fallback_actions", "failed_decisions",
           "weights_refused", "pose_missing", "pose_stale", "pose_malformed")


class NodeDiagnostics:
    """``diagnostics()`` (the values) and ``_publish_diagnostics`` (the timer's)."""

    def diagnostics(self) -> dict[str, str]:
        """Counts since start and the decision latency of the last window, as strings (DiagnosticStatus)."""
        window, self.decider.window_latencies = self.decider.window_latencies, []
        values = {"runtime": self.runtime_name, "checkpoint_sha256": self.checkpoint_sha256[:12],
                  "policy_version": str(self.policy_version), "weights_refusal": self.weights_refusal,
                  "robots": str(len(self.names)), "actions_sent": str(self.actions_sent),
                  "detections_dropped": str(self.dropped_detections)}
        for key in COUNTED:
            values[key] = str(self.counts.get(key, 0))
        if self.weights is not None:                 # refusals by reason, the fetch running (ros.weights_follower)
            values.update(self.weights.diagnostics())
        values["operator_services"] = "on" if self.operator else "off"
        values["runtime_controls"] = "on" if self.runtime_controls else "off"
        if self.operator is not None:                # signed operator requests: accepted, refused by reason
            values.update(self.operator.diagnostics())
        values["frame_authentication"] = "off"
        if self.frame_gate is not None:              # frames verified, waiting for their tag, refused by reason
            values.update(self.frame_gate.diagnostics())
        if self.ros_sports is not None:
            values.update(self.ros_sports.diagnostics())
        values["pose_input"] = "yes" if self.pose_wanted else "no"
        values["pose_refusal"] = self.pose_refusal
        values["latency_median_ms"] = f"{statistics.median(window):.2f}" if window else "0.00"
        values["latency_max_ms"] = f"{max(window):.2f}" if window else "0.00"
        return values

    def _publish_diagnostics(self) -> None:
        values = self.diagnostics()
        new = {k: int(values[k]) - self._reported[k] for k in WATCHED if int(values[k]) > self._reported[k]}
        self._reported.update(new)
        status = DiagnosticStatus(level=DiagnosticStatus.WARN if new else DiagnosticStatus.OK, name="dynenv_policy",
                                  message=", ".join(f"{v} {k}" for k, v in new.items()) if new else "ok",
                                  hardware_id=self.get_fully_qualified_name(),
                                  values=[KeyValue(key=k, value=v) for k, v in values.items()])
        msg = DiagnosticArray(status=[status])
        msg.header.stamp = self.get_clock().now().to_msg()
        self.diagnostics_pub.publish(msg)
        self._diagnostics_sent += 1
        if new or self._diagnostics_sent % 10 == 1:         # the log gets one line in ten, or any new trouble
            self.get_logger().info(" ".join(f"{k}={v}" for k, v in values.items() if v not in ("0", "0.00", "")))
