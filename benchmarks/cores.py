"""dynenv-bench cores: how far this machine's cores scale at all, by the size of the memory a process works in.

Why: the vectorised batch's target (two cores ≥ 1.8x one) presumes two cores that do not slow each other down. On a
virtual machine they may share an L3 cache, memory bandwidth or a physical core, and nothing in ``lscpu`` says which.
This suite measures it directly: each workload runs alone in a process pinned to the first core, then as two copies
started together, pinned to the first two cores; the scaling is ``2 x alone's time / the slower copy's time`` (2.0:
independent cores). It is given twice: by wall time, and by CPU time (each process's own ``time.process_time()``
around its sweeps). On a shared machine wall time also counts the time other processes held the core, and blames
them on the cores; CPU time does not — but a stall on a shared cache or on memory is CPU time, so contention between
the two cores still shows in the CPU-time scaling. ``--repeat`` pairs of runs (alone, then two at once): each figure
is the median and [min, max] over them (``benchmarks/timing.py``). The workloads differ only in their working set:

- ``interpreter``: a Python loop on a few integers (no memory traffic);
- ``numpy-l2`` / ``numpy-l3`` / ``numpy-dram``: an elementwise multiply over 256 KiB, 8 MiB and 160 MiB arrays
  (inside a core's L2 on common x86 servers, inside a shared L3, beyond every cache).

A workload that scales to ≈ 2.0 in L2 but clearly less in L3 or DRAM means the two cores contend for the shared
caches and memory: any program whose working set leaves L2 (a Python simulator does) cannot reach 2x there.
"""
from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import os
import platform
from typing import Any

from benchmarks.timing import Clock, Reading, format_stat, print_table, stat

# workload -> number of float64 elements it sweeps (0: the interpreter loop)
WORKLOADS = {"interpreter": 0, "numpy-l2": 32 * 1024, "numpy-l3": 1024 * 1024, "numpy-dram": 20 * 1024 * 1024}
PYTHON_LOOP = 100_000       # interpreter iterations in one repetition of ``interpreter``


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--seconds", type=float, default=2.0, help="about how long one timed run lasts")
    parser.add_argument("--workloads", nargs="+", choices=tuple(WORKLOADS), default=list(WORKLOADS))
    parser.add_argument("--json", action="store_true")


def _work(workload: str, repetitions: int) -> Reading:
    """Wall and CPU seconds of ``repetitions`` sweeps of ``workload`` (the same count alone and two at once)."""
    elements = WORKLOADS[workload]
    clock = Clock()
    if elements == 0:
        start = clock.read()
        total = 0
        for i in range(repetitions * PYTHON_LOOP):
            total += i * i % 7
        return clock.read() - start
    import numpy as np
    source = np.random.default_rng(0).random(elements)
    target = np.empty_like(source)
    np.multiply(source, 1.0001, out=target)   # touch both arrays once before timing
    start = clock.read()
    for _ in range(repetitions):
        np.multiply(source, 1.0001, out=target)
    return clock.read() - start


def _repetitions(workload: str, seconds: float) -> int:
    """How many sweeps last about ``seconds`` here, from a short trial in this process."""
    trial = 1
    while (elapsed := _work(workload, trial).wall_s) < 0.05:
        trial *= 2
    return max(1, round(trial * seconds / elapsed))


def _pinned(core: int, workload: str, repetitions: int, start: Any, results: Any) -> None:
    os.sched_setaffinity(0, {core})
    start.wait()
    results.put((core, _work(workload, repetitions)))


def _timed(cores: list[int], workload: str, repetitions: int) -> list[Reading]:
    """Wall and CPU time of each of ``len(cores)`` copies of ``workload``, started together, one pinned to each
    core."""
    context = mp.get_context("spawn")
    start, results = context.Barrier(len(cores) + 1), context.Queue()
    processes = [context.Process(target=_pinned, args=(core, workload, repetitions, start, results)) for core in cores]
    for process in processes:
        process.start()
    start.wait()
    times = [results.get(timeout=600)[1] for _ in cores]
    for process in processes:
        process.join()
    return times


def run(args: argparse.Namespace) -> int:
    if args.seconds <= 0:
        print("--seconds must be positive")
        return 2
    allowed = sorted(os.sched_getaffinity(0))
    if len(allowed) < 2:
        print("dynenv-bench cores needs two CPUs this process may use")
        return 2
    figures: dict[str, Any] = {"suite": "cores", "cores": allowed[:2], "machine": platform.processor() or platform.machine(),
                               "repeat": args.repeat, "workloads": {}}
    for workload in args.workloads:
        repetitions = _repetitions(workload, args.seconds)
        alone, together = [], []          # per pair of runs: one copy alone, the slower of two at once
        for _ in range(args.repeat):
            alone.append(_timed(allowed[:1], workload, repetitions)[0])
            pair = _timed(allowed[:2], workload, repetitions)
            together.append(Reading(max(r.wall_s for r in pair), max(r.cpu_s for r in pair)))
        figures["workloads"][workload] = {
            "alone_s": stat((r.wall_s for r in alone), 3), "two_at_once_s": stat((r.wall_s for r in together), 3),
            "scaling": stat((2 * a.wall_s / t.wall_s for a, t in zip(alone, together)), 2),
            "alone_cpu_s": stat((r.cpu_s for r in alone), 3),
            "two_at_once_cpu_s": stat((r.cpu_s for r in together), 3),
            "cpu_scaling": stat((2 * a.cpu_s / t.cpu_s for a, t in zip(alone, together)), 2)}
    if args.json:
        print(json.dumps(figures))
    else:
        print_table(f"two cores against one, median [min–max] of {args.repeat} (2.00 = independent cores)",
                    [(name, f"by wall time {format_stat(row['scaling'], '{:.2f}')}x (alone "
                            f"{row['alone_s']['median']} s, two at once {row['two_at_once_s']['median']} s); "
                            f"by CPU time {format_stat(row['cpu_scaling'], '{:.2f}')}x (alone "
                            f"{row['alone_cpu_s']['median']} s, two at once {row['two_at_once_cpu_s']['median']} s)")
                     for name, row in figures["workloads"].items()])
    return 0
