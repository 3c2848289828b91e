"""Launch-free ROS 2 test harness.

- Each pytest-xdist worker gets its own ROS_DOMAIN_ID (derived from the run id, so two concurrent test runs on one
  machine are unlikely to meet) and discovery is limited to this host; subprocesses inherit both.
- ``ros_context`` gives each test its own rclpy Context; ``make_node`` creates nodes in it; ``executor`` spins them.
- Markers (pytest.ini): ``ros`` is applied here by test/ros_marking.py's rules (the fixtures above, or a module that
  imports ROS), or by hand where a test starts ROS only in its subprocesses; while a test that is not ``ros`` runs,
  ROS is made unavailable to it and its subprocesses, so a missing mark fails the test instead of hiding in
  ``make test-fast``. ``slow`` is applied here from test/slow_marking.py's measured list.
"""
from __future__ import annotations

import hashlib
import os
import sys
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent
# One BLAS / OpenMP thread per process, set before numpy or torch load (they read it then), inherited by the
# processes tests start. `-n 2` gives each core a worker already; a second thread per worker makes the two wait for
# each other, and OpenBLAS spins while it waits: the perception leak test took 5x the CPU with its default threads.
for _variable in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_variable, "1")
sys.path.insert(0, str(Path(__file__).resolve().parent))  # test helpers (ros_harness) importable from tests

import ros_marking  # noqa: E402 (test helpers: importable only after the line above)
import slow_marking  # noqa: E402

ROS_GUARD = ros_marking.RosGuard()
SLOW_ENTRIES_MATCHED = pytest.StashKey[set[str]]()
FILES_COLLECTED = pytest.StashKey[set[str]]()


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


@pytest.hookimpl(tryfirst=True)   # before -m deselects: every collected test is seen
def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """The ``ros`` mark for every test that uses the ROS fixtures or whose module imports ROS; ``slow`` for the
    measured ones. Which slow-list entries named a collected test is kept for test_ros_marking.py."""
    matched: set[str] = set()
    for item in items:
        module = getattr(item, "module", None)
        module_file = Path(module.__file__) if module is not None and module.__file__ else None
        if item.get_closest_marker("ros") is None and (
                ros_marking.ROS_FIXTURES.intersection(getattr(item, "fixturenames", ())) or (
                    module_file is not None and ros_marking.module_uses_ros(module_file))):
            item.add_marker(pytest.mark.ros)
        if slow_marking.is_slow(item.nodeid):
            item.add_marker(pytest.mark.slow)
            matched.update(slow_marking.key_of(item.nodeid))
    config.stash[SLOW_ENTRIES_MATCHED] = matched
    config.stash[FILES_COLLECTED] = {Path(str(item.path)).name for item in items}


@pytest.hookimpl(tryfirst=True)
def pytest_runtest_setup(item: pytest.Item) -> None:
    if item.get_closest_marker("ros") is None:
        ROS_GUARD.arm(item.nodeid)


@pytest.hookimpl(wrapper=True)
def pytest_runtest_teardown(item: pytest.Item, nextitem: pytest.Item | None) -> Iterator[None]:
    try:
        return (yield)
    finally:
        ROS_GUARD.disarm()


@pytest.hookimpl(wrapper=True)
def pytest_runtest_makereport(item: pytest.Item, call: pytest.CallInfo[None]) -> Iterator[pytest.TestReport]:
    """A failing test that is not ``ros`` says that ROS was unavailable to it, when ROS is what failed."""
    report: pytest.TestReport = yield
    if report.failed and item.get_closest_marker("ros") is None:
        text = report.longreprtext + "".join(content for _, content in report.sections)
        if ros_marking.UNAVAILABLE_RMW in text or "not marked `ros`" in text:
            report.sections.append(("ros marker", ros_marking.hint(item.nodeid)))
    return report


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
    failed: list[BaseException] = []

    def factory(name_or_class: str | type, **options: object) -> Node:
        """A plain Node by name, or an instance of one of our node classes, in this test's context."""
        if isinstance(name_or_class, str):
            node = Node(name_or_class, context=ros_context, **options)
        else:
            try:
                node = name_or_class(context=ros_context, **options)
            except Exception as error:
                failed.append(error)
                raise
        nodes.append(node)
        return node

    yield factory
    for node in nodes:
        node.destroy_node()
    if failed:
        # A node class that raised in its constructor (a test of a bad parameter) left a half-built node: its
        # publishers, services and its DDS participant stay on this worker's domain, seen by every later test's
        # graph, until the traceback's reference cycle is collected (test_inventory.py met a leaked policy_node).
        failed.clear()
        import gc
        gc.collect()


@pytest.fixture
def executor(ros_context: object) -> Iterator[object]:
    from rclpy.executors import SingleThreadedExecutor

    executor = SingleThreadedExecutor(context=ros_context)
    yield executor
    executor.shutdown()
