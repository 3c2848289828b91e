"""Running a node process that must stop cleanly on SIGINT/SIGTERM: ``run_node`` (``node_runner``) with signal
handling of its own, for the bag tools (the recorder drains what is on its way; the player exits 0 mid-callback).
"""
from __future__ import annotations

import signal
from collections.abc import Callable, Sequence
from typing import Any

from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.node import Node

from dynenv_ros.ros.node_runner import run_node

RCLError = _rclpy.RCLError


def run_until_signal(make_node: Callable[[], Node], args: Sequence[str] | None = None) -> int:
    """``run_node`` for nodes that must exit 0 on SIGINT/SIGTERM even while a callback is running.

    rclpy's handler (installed by ``rclpy.init``) shuts the context down and then calls the Python handler that was
    there before. Two things go wrong with the defaults: Python's SIGINT handler raises KeyboardInterrupt wherever
    the interpreter is, and a signal that arrives during a callback makes the executor's next wait raise RCLError
    ("context is not valid") instead of ExternalShutdownException, i.e. a traceback and exit status 1. Here the
    Python handlers only record the signal, and an RCLError after a recorded signal is a normal shutdown (exit 0).
    ``run_node``'s ``finally`` has destroyed the node either way.
    """
    received: list[int] = []
    stop_signals = (signal.SIGINT, signal.SIGTERM)
    previous = {s: signal.signal(s, lambda signum, frame: received.append(signum)) for s in stop_signals}
    try:
        return run_node(make_node, args)
    except RCLError:
        if received:
            return 0
        raise
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)


def run_draining(make_node: Callable[[], Any], args: Sequence[str] | None = None) -> int:
    """Run a node that drains on SIGINT/SIGTERM (the recorder: its ``request_stop(drain)``) instead of letting rclpy
    shut the context down at once.

    A recorder is stopped right after the publishers finish (the main job's graph sends SIGINT when the simulator
    exits); messages they already sent may still wait in this node's queue, and rclpy's own handler would drop
    them. So rclpy's handlers are uninstalled and ours ask the node to stop after draining (``request_stop``); a
    second signal stops without draining, a third raises KeyboardInterrupt (run_node still finishes the bag).
    """
    from rclpy.signals import uninstall_signal_handlers

    received: list[int] = []
    nodes: list[Any] = []

    def on_signal(signum: int, frame: Any) -> None:
        received.append(signum)
        if len(received) >= 3:
            raise KeyboardInterrupt
        if nodes:
            nodes[0].request_stop(drain=len(received) == 1)
        # else the node is still being built (its subscriptions may already be matched, so a publisher can have
        # sent and signalled already): make() passes the stop on once it exists, and the bag is still finished

    def make() -> Any:
        uninstall_signal_handlers()   # restores on_signal, which was installed before rclpy.init
        node = make_node()
        nodes.append(node)
        if received:
            node.request_stop(drain=len(received) == 1)
        return node

    stop_signals = (signal.SIGINT, signal.SIGTERM)
    previous = {s: signal.signal(s, on_signal) for s in stop_signals}
    try:
        return run_node(make, args)
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)


__all__ = ["RCLError", "run_until_signal", "run_draining"]
