"""Launch-free helpers for node tests: spin an executor until a condition holds or a deadline passes."""
from __future__ import annotations

import time
from collections.abc import Callable

from rclpy.executors import Executor


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
