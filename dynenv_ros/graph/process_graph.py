"""Start nodes as processes on an isolated ROS domain, wait for the ones that end the run, stop the rest cleanly.

Each node runs ``python -m <module> --ros-args -r __node:=<name> -p k:=v ...`` with its output in
``<run_dir>/<name>.log``. Stopping sends SIGINT (rclpy's clean shutdown), then SIGTERM, then SIGKILL.
"""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

STOP_GRACE_S = 5.0


@dataclass(frozen=True)
class NodeLaunch:
    """One node process of a graph."""
    name: str
    module: str
    parameters: dict[str, Any] = field(default_factory=dict)
    ends_run: bool = False  # the run is over when every node with ends_run has exited
    namespace: str = ""     # e.g. "/game_1": the node's topics are the game's (ros/topics.py)
    remaps: dict[str, str] = field(default_factory=dict)   # topic -> the name the node uses for it instead

    def command(self) -> list[str]:
        args = [sys.executable, "-m", self.module, "--ros-args", "-r", f"__node:={self.name}"]
        if self.namespace:
            args += ["-r", f"__ns:={self.namespace}"]
        for topic, replacement in self.remaps.items():
            args += ["-r", f"{topic}:={replacement}"]
        for key, value in self.parameters.items():
            args += ["-p", f"{key}:={_parameter_literal(value)}"]
        return args


@dataclass
class NodeOutcome:
    name: str
    exit_code: int | None  # None: still running at the deadline and had to be stopped
    log_path: Path
    stopped_by_graph: bool


@dataclass
class GraphOutcome:
    nodes: list[NodeOutcome]
    wall_time_s: float
    timed_out: bool

    @property
    def ok(self) -> bool:
        return not self.timed_out and all(n.exit_code == 0 or n.stopped_by_graph for n in self.nodes)


def _parameter_literal(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return f"'{value}'" if value else "''"
    return repr(value)


def isolated_environment(domain_id: int) -> dict[str, str]:
    """The caller's environment on its own ROS domain, discovery limited to this host."""
    return dict(graph_environment(domain_id), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")


def graph_environment(domain_id: int) -> dict[str, str]:
    """The caller's environment on ROS domain ``domain_id``, discovery as the caller has it (the user's own tools —
    RViz, ros2 topic, a second machine — see the graph)."""
    if not 0 <= domain_id <= 101:
        raise ValueError(f"ROS domain id must be in [0, 101], got {domain_id}")
    return dict(os.environ, ROS_DOMAIN_ID=str(domain_id), PYTHONUNBUFFERED="1")


def run_graph(nodes: list[NodeLaunch], run_dir: Path, domain_id: int, timeout_s: float,
              isolate: bool = True) -> GraphOutcome:
    if not any(n.ends_run for n in nodes):
        raise ValueError("a graph needs at least one node with ends_run=True, or it never finishes")
    if len({n.name for n in nodes}) != len(nodes):
        raise ValueError("node names in a graph must be unique")
    run_dir.mkdir(parents=True, exist_ok=True)
    env = isolated_environment(domain_id) if isolate else graph_environment(domain_id)
    started = time.monotonic()
    processes: dict[str, subprocess.Popen] = {}
    logs: dict[str, Path] = {}
    try:
        for node in nodes:
            logs[node.name] = run_dir / f"{node.name}.log"
            with logs[node.name].open("w") as log:
                processes[node.name] = subprocess.Popen(node.command(), env=env, stdout=log,
                                                        stderr=subprocess.STDOUT)
        finishers = [processes[n.name] for n in nodes if n.ends_run]
        deadline = started + timeout_s
        while time.monotonic() < deadline and any(p.poll() is None for p in finishers):
            time.sleep(0.05)
        timed_out = any(p.poll() is None for p in finishers)
    finally:
        stopped = {name for name, process in processes.items() if process.poll() is None}
        _stop_all(list(processes.values()))
    outcomes = [NodeOutcome(n.name, None if n.name in stopped and n.ends_run else processes[n.name].returncode,
                            logs[n.name], n.name in stopped and not n.ends_run) for n in nodes]
    return GraphOutcome(outcomes, time.monotonic() - started, timed_out)


def _stop_all(processes: list[subprocess.Popen]) -> None:
    for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGKILL):
        running = [p for p in processes if p.poll() is None]
        if not running:
            return
        for process in running:
            process.send_signal(sig)
        deadline = time.monotonic() + STOP_GRACE_S
        while time.monotonic() < deadline and any(p.poll() is None for p in running):
            time.sleep(0.02)
