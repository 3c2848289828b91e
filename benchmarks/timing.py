"""Small timing helpers shared by the suites."""
from __future__ import annotations

import os
import time
from collections.abc import Callable


def best_rate(work: Callable[[], int], repeat: int) -> float:
    """Items per second of ``work`` (which returns how many items it processed), best of ``repeat``."""
    best = 0.0
    for _ in range(repeat):
        start = time.perf_counter()
        items = work()
        best = max(best, items / (time.perf_counter() - start))
    return best


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
