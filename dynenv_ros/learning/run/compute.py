"""What a training run cost, measured while it ran: wall and CPU seconds (this process and every process it
started: rollout workers, world workers), the load average the machine carried meanwhile, and the machine. A
budget claim ("30 minutes a seed") is read from this record, never projected from a benchmark.

A resumed run is several *segments*; each keeps its own record, so a reader can tell an uninterrupted run (one
segment) from a pieced-together one. A segment killed between checkpoints is recorded up to its last checkpoint:
the work after it is redone by the next segment and counted there.
"""
from __future__ import annotations

import os
import platform
import time
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

_TICKS = os.sysconf("SC_CLK_TCK") if hasattr(os, "sysconf") else 100


def machine() -> dict[str, Any]:
    """Cores and CPU model: the figures that say which machine a wall time belongs to."""
    model = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                model = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return {"cores": os.cpu_count(), "cpu_model": model, "system": platform.system(), "node": platform.node()}


def _process_table() -> dict[int, tuple[int, float]]:
    """pid → (parent pid, CPU seconds) of every process /proc shows (Linux; empty elsewhere)."""
    table: dict[int, tuple[int, float]] = {}
    try:
        entries = os.listdir("/proc")
    except OSError:
        return table
    for entry in entries:
        if not entry.isdigit():
            continue
        try:
            stat = Path(f"/proc/{entry}/stat").read_text()
        except OSError:                 # gone meanwhile
            continue
        fields = stat[stat.rfind(")") + 2:].split()     # after "pid (comm) ": state ppid ... utime stime
        try:
            table[int(entry)] = (int(fields[1]), (int(fields[11]) + int(fields[12])) / _TICKS)
        except (IndexError, ValueError):
            continue
    return table


def cpu_seconds_of_tree(pid: int | None = None) -> float:
    """CPU seconds (user + system) of this process, its live descendants and the children it has reaped."""
    own = os.times()
    total = own.user + own.system + own.children_user + own.children_system
    table = _process_table()
    root = os.getpid() if pid is None else pid
    children: dict[int, list[int]] = {}
    for child, (parent, _) in table.items():
        children.setdefault(parent, []).append(child)
    stack = list(children.get(root, []))
    while stack:
        child = stack.pop()
        total += table[child][1]
        stack.extend(children.get(child, []))
    return total


@dataclass
class Segment:
    """One uninterrupted stretch of a run (the first start, or one --resume)."""
    started_utc: str
    env_steps_from: int
    env_steps_to: int = 0
    wall_seconds: float = 0.0
    cpu_seconds: float = 0.0
    load_average_mean: float | None = None
    load_average_max: float | None = None
    load_samples: int = 0
    machine: dict[str, Any] = field(default_factory=machine)


class ComputeMeter:
    """Measures the running segment; ``record`` gives every segment so far (the checkpoint and summary keep it)."""

    def __init__(self, env_steps: int, earlier: list[dict[str, Any]] | None = None) -> None:
        self.earlier = [dict(s) for s in earlier or []]
        self.segment = Segment(datetime.now(timezone.utc).isoformat(timespec="seconds"), env_steps)
        self._wall0 = time.perf_counter()
        self._cpu0 = cpu_seconds_of_tree()
        self._load_sum = 0.0

    def sample_load(self) -> None:
        """One reading of the 1-minute load average (called at each log line)."""
        try:
            load = os.getloadavg()[0]
        except OSError:
            return
        s = self.segment
        self._load_sum += load
        s.load_samples += 1
        s.load_average_mean = self._load_sum / s.load_samples
        s.load_average_max = load if s.load_average_max is None else max(s.load_average_max, load)

    def record(self, env_steps: int) -> dict[str, Any]:
        s = self.segment
        s.env_steps_to = env_steps
        s.wall_seconds = time.perf_counter() - self._wall0
        s.cpu_seconds = max(0.0, cpu_seconds_of_tree() - self._cpu0)
        segments = self.earlier + [dict(s.__dict__)]
        return {"segments": segments, "uninterrupted": len(segments) == 1,
                "wall_seconds": sum(float(x["wall_seconds"]) for x in segments),
                "cpu_seconds": sum(float(x["cpu_seconds"]) for x in segments),
                "env_steps": env_steps}
