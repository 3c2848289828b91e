"""What set-up costs: the no-op overhead of the README commands' bootstrap, and the size of the venv.

The bootstrap runs ``--repeat`` times; its wall and CPU seconds (the bootstrap process and what it starts, from
``getrusage(RUSAGE_CHILDREN)``) are the median and [min, max] of the runs (``benchmarks/timing.py``).
"""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from benchmarks.timing import format_stat, measure, print_table, stat

REPO = Path(__file__).resolve().parent.parent


def directory_size(path: Path) -> int:
    return sum(p.stat().st_size for p in path.rglob("*") if p.is_file() and not p.is_symlink())


def run(args) -> int:
    host_python = "python3.11"

    def bootstrap() -> int:
        subprocess.run([host_python, str(REPO / "tools" / "bootstrap.py")], check=True, cwd=REPO)
        return 1
    runs = measure(bootstrap, args.repeat, children=True)        # the bootstrap is a waited-for child
    venv = Path(sys.prefix)
    figures = {"bootstrap_s": stat((r.wall_s for r in runs), 3), "bootstrap_cpu_s": stat((r.cpu_s for r in runs), 3),
               "venv_mib": round(directory_size(venv) / 2**20),
               "torch_mib": round(directory_size(venv / "lib/python3.11/site-packages/torch") / 2**20),
               "repeat": args.repeat}
    if getattr(args, "json", False):
        print(json.dumps(figures))
        return 0
    print_table(f"Set-up (median [min–max] of {args.repeat} runs)", [
        ("bootstrap with nothing changed (s)", format_stat(figures["bootstrap_s"], "{:.2f}")),
        ("  of which CPU (s)", format_stat(figures["bootstrap_cpu_s"], "{:.2f}")),
        ("venv size (MiB)", f"{figures['venv_mib']:,}"),
        ("  of which torch (MiB)", f"{figures['torch_mib']:,}"),
    ])
    return 0
