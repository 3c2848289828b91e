"""dynenv-bench cores: the machine's own two-core scaling, which bounds the vectorised batch's (docs/benchmarks.md)."""
import json
import os
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
COMMAND = [sys.executable, "-m", "benchmarks", "cores", "--repeat", "1"]


def test_cores_benchmark_times_each_workload_alone_and_two_at_once():
    result = subprocess.run(COMMAND + ["--seconds", "0.1", "--workloads", "interpreter", "numpy-l2", "--json"],
                            capture_output=True, text=True, timeout=120, cwd=REPO)
    if len(os.sched_getaffinity(0)) < 2:   # a run pinned to one core (the suite needs two): refused, and said why
        assert result.returncode == 2 and "needs two CPUs" in result.stdout
        return
    assert result.returncode == 0, result.stderr
    figures = json.loads(result.stdout)
    assert figures["cores"] == sorted(os.sched_getaffinity(0))[:2] and set(figures["workloads"]) == {"interpreter", "numpy-l2"}
    for row in figures["workloads"].values():
        assert row["alone_s"] > 0 and row["two_at_once_s"] > 0
        # the scaling is computed from the unrounded times; the printed ones are rounded to 1 ms of ≥ 0.05 s
        assert abs(row["scaling"] - 2 * row["alone_s"] / row["two_at_once_s"]) < 0.05


def test_cores_benchmark_refuses_a_duration_that_is_not_positive():
    result = subprocess.run(COMMAND + ["--seconds", "0"], capture_output=True, text=True, timeout=60, cwd=REPO)
    assert result.returncode == 2 and "--seconds must be positive" in result.stdout
