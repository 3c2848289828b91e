"""The Jazzy main() idiom shared by every node: init, spin, clean shutdown on SIGINT/SIGTERM, exit status."""
from __future__ import annotations

from collections.abc import Callable, Sequence

import sys

import rclpy
from rclpy.exceptions import ParameterException
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node


class NodeExit(Exception):
    """Raised from a callback to stop spinning with an exit status (e.g. a self-check that finished)."""

    def __init__(self, status: int) -> None:
        super().__init__(status)
        self.status = status


def run_node(make_node: Callable[[], Node], args: Sequence[str] | None = None) -> int:
    """Create the node, spin it until shutdown or NodeExit, and return the process exit status."""
    rclpy.init(args=args)
    node = None
    status = 0
    try:
        node = make_node()
        executor = SingleThreadedExecutor()
        executor.add_node(node)
        executor.spin()
    except NodeExit as stop:
        status = stop.status
    except ParameterException as error:  # out of range or wrong type: refuse with the reason
        print(f"parameter error: {error}", file=sys.stderr, flush=True)
        status = 2
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except Exception as error:  # a signal during a callback: the next wait finds the context already shut down
        if type(error).__name__ != "RCLError" or (node is not None and node.context.ok()):
            raise
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    return status
