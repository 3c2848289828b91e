"""Self-check talker: publishes reproducible samples of every dynenv_msgs message and serves every service."""
from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from rclpy.node import Node

from dynenv_ros.ros.diagnostics import Heartbeat
from dynenv_ros.ros.interfaces import message_types, service_types
from dynenv_ros.ros.node_runner import run_node
from dynenv_ros.ros.parameters import declare_int
from dynenv_ros.ros.qos import latched
from dynenv_ros.ros.selfcheck import expected_message, expected_response, service_name_for, topic_for


class SelfCheckTalker(Node):
    def __init__(self, **node_options: Any) -> None:
        """``node_options`` go to rclpy's Node (context, parameter_overrides, ...) for in-process tests."""
        super().__init__("selfcheck_talker", **node_options)
        self.seed = declare_int(self, "seed", 0, 0, 2**31 - 1, "Seed of the published samples.")
        self.samples_per_type = declare_int(self, "samples_per_type", 3, 1, 1000,
                                            "Messages published per message type (kept for late joiners).")
        self.served = 0
        self.heartbeat = Heartbeat(self, "selfcheck talker", lambda: {"services_answered": self.served})
        self.service_servers = [self.create_service(cls, service_name_for(name), self._answer(cls))
                          for name, cls in service_types().items()]
        self.sample_publishers = []
        for interface in message_types():
            publisher = self.create_publisher(interface.cls, topic_for(interface), latched(self.samples_per_type))
            for index in range(self.samples_per_type):
                publisher.publish(expected_message(interface, self.seed, index))
            self.sample_publishers.append(publisher)
        self.get_logger().info(f"published {self.samples_per_type} samples of {len(self.sample_publishers)} message "
                               f"types; serving {len(self.service_servers)} services")

    def _answer(self, service_cls: type):
        def handle(request: Any, response: Any) -> Any:
            self.served += 1
            return expected_response(service_cls, request)
        return handle


def main(args: Sequence[str] | None = None) -> int:
    return run_node(SelfCheckTalker, args)


if __name__ == "__main__":
    raise SystemExit(main())
