"""Self-check listener: receives every interface from the talker, verifies it field by field, and reports.

Exits 0 when every message type and service checked out, 1 otherwise (or on timeout). Writes a JSON report when
``report_path`` is set.
"""
from __future__ import annotations

import json
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from rclpy.node import Node

from dynenv_ros.ros.diagnostics import Heartbeat
from dynenv_ros.ros.interfaces import InterfaceType, generated_type_hash, message_types, sample_message, \
    service_types
from dynenv_ros.ros.node_runner import NodeExit, run_node
from dynenv_ros.ros.parameters import declare_float, declare_int, declare_str
from dynenv_ros.ros.qos import latched
from dynenv_ros.ros.selfcheck import InterfaceCheck, build_report, expected_message, expected_response, \
    format_report, message_checks, sample_seed, service_check_name, service_name_for, topic_for


class SelfCheckListener(Node):
    def __init__(self, **node_options: Any) -> None:
        """``node_options`` go to rclpy's Node (context, parameter_overrides, ...) for in-process tests."""
        super().__init__("selfcheck_listener", **node_options)
        self.seed = declare_int(self, "seed", 0, 0, 2**31 - 1, "Seed the talker used.")
        self.samples_per_type = declare_int(self, "samples_per_type", 3, 1, 1000, "Samples expected per type.")
        self.timeout_s = declare_float(self, "timeout_s", 30.0, 0.1, 3600.0, "Give up after this long (wall s).")
        self.report_path = declare_str(self, "report_path", "", "Where to write the JSON report (empty: none).")
        self.checks: dict[str, InterfaceCheck] = message_checks(self.samples_per_type)
        self.hash_problems: list[str] = []
        self.receivers = [
            self.create_subscription(t.cls, topic_for(t), self._receiver(t), latched(self.samples_per_type))
            for t in message_types()]
        self.service_classes = service_types()
        self.service_clients = {name: self.create_client(cls, service_name_for(name))
                                for name, cls in self.service_classes.items()}
        for name in self.service_clients:
            self.checks[service_check_name(name)] = InterfaceCheck(service_check_name(name), self.samples_per_type)
        self._pending: list[Any] = []
        self._started = time.monotonic()
        self._timer = self.create_timer(0.05, self._tick)
        self.heartbeat = Heartbeat(self, "selfcheck listener", lambda: {
            "interfaces_checked": len(self.checks), "hash_problems": len(self.hash_problems)})

    def _receiver(self, interface: InterfaceType):
        check = self.checks[interface.name]

        def receive(message: Any) -> None:
            if check.received >= check.expected:
                check.problems.append("more messages than were published")
                return
            check.record(expected_message(interface, self.seed, check.received), message)
        return receive

    def _call_services(self) -> None:
        for name, client in self.service_clients.items():
            check = self.checks[service_check_name(name)]
            busy = any(pending[0] == name for pending in self._pending)  # one call in flight per service
            if busy or check.received >= check.expected or not client.service_is_ready():
                continue
            service_cls = self.service_classes[name]
            request = sample_message(service_cls.Request, sample_seed(self.seed, check.received))
            self._pending.append((name, request, client.call_async(request)))

    def _collect_responses(self) -> None:
        still_pending = []
        for name, request, future in self._pending:
            if not future.done():
                still_pending.append((name, request, future))
                continue
            self.checks[service_check_name(name)].record(expected_response(self.service_classes[name], request),
                                                           future.result())
        self._pending = still_pending

    def _check_type_hashes(self) -> None:
        """The hash each publisher advertises must be rosidl's hash of our .msg (catches stale builds)."""
        for interface in message_types():
            publishers = self.get_publishers_info_by_topic(self.resolve_topic_name(topic_for(interface)))
            if not publishers:
                self.hash_problems.append(f"{interface.name}: no publisher seen, hash not checked")
            for info in publishers:
                advertised, generated = str(info.topic_type_hash), generated_type_hash(interface.name)
                if advertised != generated:
                    self.hash_problems.append(f"{interface.name}: advertised {advertised} != {generated}")

    def _tick(self) -> None:
        self._collect_responses()
        self._call_services()
        done = all(c.received >= c.expected for c in self.checks.values())
        if done or time.monotonic() - self._started > self.timeout_s:
            self._finish(timed_out=not done)

    def _finish(self, timed_out: bool) -> None:
        self._check_type_hashes()
        report = build_report(list(self.checks.values()), self.hash_problems, timed_out,
                              time.monotonic() - self._started)
        print(format_report(report), flush=True)
        if self.report_path:
            path = Path(self.report_path)
            path.parent.mkdir(parents=True, exist_ok=True)
            tmp = path.with_suffix(path.suffix + ".tmp")
            tmp.write_text(json.dumps(report, indent=1))
            tmp.replace(path)  # atomic: a reader never sees half a report
        raise NodeExit(0 if report["ok"] else 1)


def main(args: Sequence[str] | None = None) -> int:
    return run_node(SelfCheckListener, args)


if __name__ == "__main__":
    raise SystemExit(main())
