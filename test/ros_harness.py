"""Launch-free helpers for node tests: spin an executor until a condition holds or a deadline passes."""
from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

from rclpy.executors import Executor

# How long an attacker process (test/*_attacker.py) runs when its test kills it after its wait: longer than any
# wait, so on a loaded machine, where a motion period can take seconds, the attacker is still there when it counts.
ATTACKER_OUTLIVES_THE_TEST_S = 600


def spin_until(executor: Executor, condition: Callable[[], bool], timeout_s: float = 10.0,
               step_s: float = 0.02) -> bool:
    """Spin until ``condition()`` is true (returns True) or ``timeout_s`` passes (returns False)."""
    deadline = time.monotonic() + timeout_s
    while True:
        if condition():
            return True
        if time.monotonic() >= deadline:
            return False
        executor.spin_once(timeout_sec=step_s)


def call_idempotent(executor: Executor, client, request, timeout_s: float = 20.0, resend_after_s: float = 2.0):
    """Call a service whose answer does not depend on how often it is asked, re-sending while no answer came.

    ``service_is_ready()`` only says the server's request reader matched ours; its reply writer may not yet have
    matched our reply reader, and DDS then drops the reply (a known ROS 2 discovery race across processes).
    Returns the response, or None when none arrived within ``timeout_s``.
    """
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        future = client.call_async(request)
        if spin_until(executor, future.done, min(resend_after_s, max(0.0, deadline - time.monotonic()))):
            return future.result()
        client.remove_pending_request(future)
    return None


def finish_attacker(attacker: Any) -> dict:
    """Stop an attacker process (test/*_attacker.py) and return its report: the last JSON line it printed."""
    import json
    if attacker.poll() is None:
        attacker.terminate()
    output = attacker.communicate(timeout=30)[0]
    lines = [line for line in output.splitlines() if line.startswith("{")]
    assert lines, output[-3000:]
    return json.loads(lines[-1])


def spin_then_report(node: Any, seconds: float, sent: dict[str, int]) -> None:
    """An attacker process's last act: spin ``node`` for ``seconds``, print what it sent (the test reads the line),
    and shut ROS down."""
    import rclpy
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        rclpy.spin_once(node, timeout_sec=0.05)
    print("sent " + " ".join(f"{k}={n}" for k, n in sorted(sent.items())), flush=True)
    node.destroy_node()
    rclpy.shutdown()
