"""What set-up costs: the no-op overhead of the README commands' bootstrap, and the size of the venv."""
from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

from benchmarks.timing import print_table

REPO = Path(__file__).resolve().parent.parent


def directory_size(path: Path) -> int:
    return sum(p.stat().st_size for p in path.rglob("*") if p.is_file() and not p.is_symlink())


def run(args) -> int:
    repeat = args.repeat
    host_python = "python3.11"
    durations = []
    for _ in range(repeat):
        start = time.perf_counter()
        subprocess.run([host_python, str(REPO / "tools" / "bootstrap.py")], check=True, cwd=REPO)
        durations.append(time.perf_counter() - start)
    venv = Path(sys.prefix)
    print_table("Set-up", [
        ("bootstrap with nothing changed (s, best)", f"{min(durations):.2f}"),
        ("venv size (MiB)", f"{directory_size(venv) / 2**20:,.0f}"),
        ("  of which torch (MiB)", f"{directory_size(venv / 'lib/python3.11/site-packages/torch') / 2**20:,.0f}"),
    ])
    return 0
