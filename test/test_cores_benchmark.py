"""dynenv-bench cores: the machine's own two-core scaling, which bounds the vectorised batch's (docs/benchmarks.md)."""
import json
import os
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
COMMAND = [sys.executable, "-m", "benchmarks", "cores", "--repeat", "2"]
HALF_MS = 0.0005             # the printed times' rounding


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
        # every figure is the median and range of the --repeat runs, by wall time and by CPU time
        for key in ("alone_s", "two_at_once_s", "scaling", "alone_cpu_s", "two_at_once_cpu_s", "cpu_scaling"):
            figure = row[key]
            assert len(figure["runs"]) == 2 and figure["min"] <= figure["median"] <= figure["max"]
            assert figure["min"] == min(figure["runs"]) and figure["max"] == max(figure["runs"])
        assert row["alone_s"]["min"] > 0 and row["two_at_once_s"]["min"] > 0
        # a busy loop runs on the CPU: its CPU time is its wall time or less (other processes may hold the core)
        assert 0 < row["alone_cpu_s"]["min"] <= row["alone_s"]["max"] * 1.05 + 0.02
        # each run's scaling is computed from its unrounded times; the printed times are rounded to 1 ms (± 0.5 ms)
        # and the scaling to 0.01 (± 0.005), so 2 x alone / together from the printed times may differ from it by the
        # rounding's worst case — which grows as a busy machine leaves a copy little CPU time (a run of 20 ms: ± 0.1)
        for clock in ("", "cpu_"):
            times = zip(row[f"alone_{clock}s"]["runs"], row[f"two_at_once_{clock}s"]["runs"], row[f"{clock}scaling"]["runs"])
            for alone, together, scaling in times:
                assert together > HALF_MS
                worst = 0.005 + 2 * HALF_MS * (1 / (together - HALF_MS) + (alone + HALF_MS) / (together - HALF_MS) ** 2)
                assert abs(scaling - 2 * alone / together) <= worst


def test_cores_benchmark_refuses_a_duration_that_is_not_positive():
    result = subprocess.run(COMMAND + ["--seconds", "0"], capture_output=True, text=True, timeout=60, cwd=REPO)
    assert result.returncode == 2 and "--seconds must be positive" in result.stdout
