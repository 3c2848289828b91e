"""Launch-free ROS 2 test harness.

- Each pytest-xdist worker gets its own ROS_DOMAIN_ID (derived from the run id, so two concurrent test runs on one
  machine are unlikely to meet) and discovery is limited to this host; subprocesses inherit both.
- ``ros_context`` gives each test its own rclpy Context; ``make_node`` creates nodes in it; ``executor`` spins them.
"""
from __future__ import annotations

import hashlib
import os
import sys
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(Path(__file__).resolve().parent))  # test helpers (ros_harness) importable from tests


def worker_domain_id() -> int:
    run_id = os.environ.get("PYTEST_XDIST_TESTRUNUID", str(os.getpid()))
    worker = os.environ.get("PYTEST_XDIST_WORKER", "gw0")
    index = int(worker[2:]) if worker.startswith("gw") and worker[2:].isdigit() else 0
    base = 1 + int(hashlib.sha256(run_id.encode()).hexdigest(), 16) % 24 * 4
    return base + index % 4  # 1..100, distinct for up to 4 workers of one run


def pytest_configure(config: pytest.Config) -> None:
    os.environ["ROS_DOMAIN_ID"] = str(worker_domain_id())
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    os.environ.pop("ROS_LOCALHOST_ONLY", None)
    os.environ["PYTHONUNBUFFERED"] = "1"
    # a test (or a documented command the doc test runs) that evaluates on the test split appends here, never to
    # the repository's committed ledger
    import tempfile
    os.environ["DYNENV_TEST_LEDGER"] = str(Path(tempfile.gettempdir()) / f"dynenv_test_ledger_{os.getpid()}.jsonl")


@pytest.fixture
def ros_context() -> Iterator[object]:
    import rclpy
    from rclpy.context import Context

    context = Context()
    rclpy.init(context=context)
    yield context
    rclpy.try_shutdown(context=context)


@pytest.fixture
def make_node(ros_context: object) -> Iterator[Callable[..., object]]:
    from rclpy.node import Node

    nodes: list[Node] = []

    def factory(name_or_class: str | type, **options: object) -> Node:
        """A plain Node by name, or an instance of one of our node classes, in this test's context."""
        if isinstance(name_or_class, str):
            node = Node(name_or_class, context=ros_context, **options)
        else:
            node = name_or_class(context=ros_context, **options)
        nodes.append(node)
        return node

    yield factory
    for node in nodes:
        node.destroy_node()


@pytest.fixture
def executor(ros_context: object) -> Iterator[object]:
    from rclpy.executors import SingleThreadedExecutor

    executor = SingleThreadedExecutor(context=ros_context)
    yield executor
    executor.shutdown()
