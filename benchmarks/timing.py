"""Timing shared by the suites: a measurement repeated N times, reported as its median and [min, max] range, by wall
time and by CPU time.

Why both clocks: on a shared machine wall time also counts the time other processes held the core, so a wall-clock
rate blames them on the code measured (and a best-of-N picks the run they disturbed least: it flatters). CPU time
counts only what the measured processes themselves ran. Every rate is given per wall second and per CPU second; the
median says what a run typically gives, the range how far runs spread.

The JSON scheme, the same in every suite: a repeated figure is an object ::

    {"median": 1105.2, "min": 1080.0, "max": 1120.4, "runs": [1105.2, 1080.0, 1120.4]}

(``stat``); figures that do not vary between runs (settings, counts) stay plain values beside them.

API — also what ``benchmarks/train.py`` calls:

1. ``work()`` does the thing once and returns how many items it processed (env steps, frames, decisions)::

       runs = measure(work, repeat=args.repeat)           # list[Run], one per repetition
       figures.update(summarise(runs, "env_steps"))
       # {"env_steps_per_s": stat, "env_steps_per_cpu_s": stat, "wall_s": stat, "cpu_s": stat}

2. Worker processes do part of the work: their CPU time counts too. ``time.process_time()`` is this process (all its
   threads); ``pids`` adds live processes read from ``/proc/<pid>/stat`` (utime + stime; a callable is asked at
   every reading, for workers made inside ``work``); ``children=True`` adds ``getrusage(RUSAGE_CHILDREN)``, which
   only counts children already waited for (``subprocess.run``, ``Process.join``)::

       runs = measure(work, args.repeat, pids=lambda: [p.pid for p in env.worker_processes])

3. A run timed by hand (warm-up first, several phases, interleaved chunks, extra figures per run)::

       clock = Clock(pids=worker_pids)
       start = clock.read()
       ...                                      # the timed work
       span = clock.read() - start              # Reading(wall_s, cpu_s); Readings add: total = total + span
       runs.append(Run(items=steps, wall_s=span.wall_s, cpu_s=span.cpu_s,
                       extra={"ms_per_update_rollout": 1000 * rollout_s / updates}))
       figures.update(summarise(runs, "env_steps"))   # the extra figures become stats too

   ``stat(values)`` summarises any list of per-run values; ``combine([figures, ...])`` turns whole runs' figure
   dicts into one, every number a ``stat``; ``format_stat(s)`` prints one as ``1,105 [1,080–1,120]``.
"""
from __future__ import annotations

import os
import resource
import statistics
import tempfile
import time
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Union

Pids = Union[Iterable[int], Callable[[], Iterable[int]]]
_TICKS = os.sysconf("SC_CLK_TCK")


def process_cpu_seconds(pid: int) -> float:
    """User + system CPU seconds of a live process (all its threads; not its children), from ``/proc/<pid>/stat``
    (resolution: one clock tick, 10 ms on Linux). Raises ``OSError`` when the process is gone."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / _TICKS


def process_rss_mib(pid: int) -> float:
    """Resident memory of a live process, MiB, from ``/proc/<pid>/status``. Raises ``OSError`` when it is gone."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    raise OSError(f"no VmRSS for process {pid} (a zombie?)")


def children_cpu_seconds() -> float:
    """User + system CPU seconds of this process's children that have been waited for."""
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


@dataclass(frozen=True)
class Reading:
    """A point on both clocks, or (as a difference of two) a span: wall seconds and CPU seconds."""
    wall_s: float
    cpu_s: float

    def __sub__(self, other: "Reading") -> "Reading":
        return Reading(self.wall_s - other.wall_s, self.cpu_s - other.cpu_s)

    def __add__(self, other: "Reading") -> "Reading":
        return Reading(self.wall_s + other.wall_s, self.cpu_s + other.cpu_s)


ZERO = Reading(0.0, 0.0)


class Clock:
    """Wall time (``perf_counter``) and the CPU time of this process, plus that of the live processes ``pids`` and,
    with ``children=True``, of the waited-for children. A process that has gone keeps its last value read."""

    def __init__(self, pids: Pids = (), children: bool = False) -> None:
        self._pids = pids
        self._children = children
        self._last: dict[int, float] = {}

    def _pid_list(self) -> list[int]:
        return list(self._pids() if callable(self._pids) else self._pids)

    def cpu_of(self, pid: int) -> float:
        try:
            self._last[pid] = process_cpu_seconds(pid)
        except OSError:
            pass
        return self._last.get(pid, 0.0)

    def read(self) -> Reading:
        wall = time.perf_counter()
        cpu = time.process_time() + sum(self.cpu_of(pid) for pid in self._pid_list())
        if self._children:
            cpu += children_cpu_seconds()
        return Reading(wall, cpu)


@dataclass
class Run:
    """One repetition: ``items`` processed in ``wall_s`` wall seconds and ``cpu_s`` CPU seconds; ``extra``: other
    figures of this run (numbers), summarised beside the rates."""
    items: float
    wall_s: float
    cpu_s: float
    extra: dict[str, float] = field(default_factory=dict)

    @property
    def rate(self) -> float:
        return self.items / self.wall_s

    @property
    def cpu_rate(self) -> float:
        return self.items / self.cpu_s if self.cpu_s > 0 else float("inf")


def measure(work: Callable[[], float], repeat: int, pids: Pids = (), children: bool = False) -> list[Run]:
    """``work()`` run ``repeat`` times, each timed on a ``Clock(pids, children)``; it returns the items it processed."""
    clock, runs = Clock(pids, children), []
    for _ in range(repeat):
        start = clock.read()
        items = work()
        span = clock.read() - start
        runs.append(Run(items, span.wall_s, span.cpu_s))
    return runs


def runs_in_folders(measure_once: Callable[[Path], Any], repeat: int, keep: str | None = None) -> list[Any]:
    """``measure_once(folder)`` run ``repeat`` times, each in a folder of its own for logs and bags: under ``keep``
    (``run_<k>``, or ``keep`` itself for one run) where given, kept; else a temporary folder, removed."""
    runs = []
    for k in range(repeat):
        if keep:
            folder = Path(keep) / (f"run_{k}" if repeat > 1 else "")
            folder.mkdir(parents=True, exist_ok=True)
            runs.append(measure_once(folder))
        else:
            with tempfile.TemporaryDirectory() as tmp:
                runs.append(measure_once(Path(tmp)))
    return runs


def stat(values: Iterable[float], digits: int | None = 1) -> dict[str, Any]:
    """``{"median", "min", "max", "runs"}`` of per-run values (rounded to ``digits``; None: as they are)."""
    values = [float(v) for v in values]
    if not values:
        raise ValueError("stat of no runs")

    def r(v: float) -> float:
        return v if digits is None or v != v or v in (float("inf"), float("-inf")) else round(v, digits)
    return {"median": r(statistics.median(values)), "min": r(min(values)), "max": r(max(values)),
            "runs": [r(v) for v in values]}


def summarise(runs: list[Run], unit: str, digits: int = 1) -> dict[str, dict[str, Any]]:
    """The figures of ``runs``: ``<unit>_per_s`` (per wall second), ``<unit>_per_cpu_s`` (per CPU second),
    ``wall_s``, ``cpu_s`` and every ``extra`` figure, each a ``stat``."""
    figures = {f"{unit}_per_s": stat((r.rate for r in runs), digits),
               f"{unit}_per_cpu_s": stat((r.cpu_rate for r in runs), digits),
               "wall_s": stat((r.wall_s for r in runs), 6), "cpu_s": stat((r.cpu_s for r in runs), 6)}
    for key in runs[0].extra:
        figures[key] = stat((r.extra[key] for r in runs), digits)
    return figures


def combine(runs: list[Mapping[str, Any]], plain: Iterable[str] = (), digits: int | None = 4) -> dict[str, Any]:
    """The figures of several runs of one measurement (dicts with the same keys) as one: every number (not a bool)
    becomes a ``stat``, nested dicts are combined the same way; the keys in ``plain`` (settings) and anything not a
    number are taken from the first run."""
    plain = set(plain)
    out: dict[str, Any] = {}
    for key, first in runs[0].items():
        values = [run[key] for run in runs]
        if key in plain or isinstance(first, bool) or not isinstance(first, (int, float, dict)):
            out[key] = first
        elif isinstance(first, dict):
            out[key] = combine(values, plain, digits) if first else first
        else:
            out[key] = stat(values, digits)
    return out


def scaled(figure: Mapping[str, Any], factor: float, digits: int | None = 1) -> dict[str, Any]:
    """A ``stat`` multiplied by a positive constant (a derived rate: ticks/s from env steps/s)."""
    return stat((factor * v for v in figure["runs"]), digits)


def inverse(figure: Mapping[str, Any], numerator: float = 1000.0, digits: int | None = 4) -> dict[str, Any]:
    """``numerator / value`` of each run of a rate ``stat`` (ms per item from items per second)."""
    return stat((numerator / v for v in figure["runs"]), digits)


def _number(value: float) -> str:
    magnitude = abs(value)
    if magnitude >= 100 or value == int(value):
        return f"{value:,.0f}"
    return f"{value:.2f}" if magnitude >= 1 else f"{value:.4f}"


def format_stat(figure: Mapping[str, Any], fmt: str | None = None) -> str:
    """``median [min–max]`` of a ``stat`` (``fmt``: a format such as ``"{:,.0f}"``; None: by magnitude)."""
    text = _number if fmt is None else fmt.format
    return f"{text(figure['median'])} [{text(figure['min'])}–{text(figure['max'])}]"


def table_rows(figures: Mapping[str, Any], skip: Iterable[str] = ()) -> list[tuple[str, str]]:
    """(name, text) rows of a suite's figures for ``print_table``: stats as ``median [min–max]``."""
    return [(k, format_stat(v) if is_stat(v) else str(v)) for k, v in figures.items() if k not in set(skip)]


def is_stat(value: Any) -> bool:
    return isinstance(value, dict) and {"median", "min", "max"} <= set(value)


def print_table(title: str, rows: list[tuple[str, str]]) -> None:
    width = max(len(name) for name, _ in rows)
    print(title)
    for name, value in rows:
        print(f"  {name:<{width}}  {value}")


def pin_cores(cores: int) -> list[int]:
    """Restrict this process to its first ``cores`` allowed CPUs (0: leave as is); return the CPUs it may use."""
    allowed = sorted(os.sched_getaffinity(0))
    if cores > 0:
        allowed = allowed[:cores]
        os.sched_setaffinity(0, allowed)
    return allowed


def torch_threads(threads: int) -> None:
    """Intra-op threads as asked and one inter-op thread (figures per core, as the docs report them)."""
    import torch
    torch.set_num_threads(threads)
    try:
        torch.set_num_interop_threads(1)
    except RuntimeError:       # already fixed by earlier torch work in this process
        pass
