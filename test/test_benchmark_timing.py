"""benchmarks/timing.py: a measurement repeated N times is reported as its median and [min, max], by wall time and
by CPU time — the CPU time of this process, of live worker processes and of waited-for children."""
import subprocess
import sys
import time

import pytest

from benchmarks.timing import Clock, Run, combine, format_stat, measure, stat, summarise

BUSY = "import time\nend = time.process_time() + {seconds}\nwhile time.process_time() < end: pass\n"


def _busy(seconds: float) -> int:
    end = time.process_time() + seconds
    while time.process_time() < end:
        pass
    return 1


def test_stat_gives_the_median_and_range_of_the_runs():
    assert stat([3.0, 1.0, 2.0]) == {"median": 2.0, "min": 1.0, "max": 3.0, "runs": [3.0, 1.0, 2.0]}
    even = stat([4.0, 1.0, 2.0, 10.0])
    assert even["median"] == 3.0 and even["min"] <= even["median"] <= even["max"]
    assert format_stat(stat([1105.2, 1080.0, 1120.4])) == "1,105 [1,080–1,120]"
    with pytest.raises(ValueError):
        stat([])


def test_waiting_is_wall_time_not_cpu_time():
    runs = measure(lambda: (time.sleep(0.05), 10)[1], 3)
    assert len(runs) == 3 and all(run.wall_s >= 0.05 and run.cpu_s < 0.02 for run in runs)
    figures = summarise(runs, "items")
    for key in ("items_per_s", "items_per_cpu_s", "wall_s", "cpu_s"):
        assert figures[key]["min"] <= figures[key]["median"] <= figures[key]["max"]
    # 10 items in ≥ 0.05 s of wall time, but hardly any CPU time: per CPU second the rate is far higher
    assert figures["items_per_s"]["max"] <= 200 < figures["items_per_cpu_s"]["min"]


def test_computing_is_cpu_time():
    run = measure(lambda: _busy(0.1), 1)[0]
    assert 0.1 <= run.cpu_s <= run.wall_s + 0.01


def test_live_workers_and_waited_children_count_when_asked():
    worker = subprocess.Popen([sys.executable, "-c", "import sys; sys.stdin.read()\n" + BUSY.format(seconds=0.3)],
                              stdin=subprocess.PIPE)
    try:
        mine, with_worker = Clock(), Clock(pids=lambda: [worker.pid])
        before, before_worker = mine.read(), with_worker.read()
        worker.stdin.close()                 # the worker computes for 0.3 s of CPU
        while with_worker.cpu_of(worker.pid) < 0.3 and worker.poll() is None:
            time.sleep(0.02)
        spent, spent_worker = mine.read() - before, with_worker.read() - before_worker
    finally:
        worker.wait(timeout=30)
    assert spent_worker.cpu_s >= 0.25 and spent.cpu_s < 0.15          # /proc/<pid>/stat: the worker's CPU time
    runs = measure(lambda: subprocess.run([sys.executable, "-c", BUSY.format(seconds=0.2)], check=True) and 1, 1,
                   children=True)
    assert runs[0].cpu_s >= 0.2                                          # getrusage(RUSAGE_CHILDREN) once waited


def test_runs_with_extra_figures_and_whole_runs_combine():
    runs = [Run(100, 1.0, 0.5, {"ms_per_update": 10.0}), Run(100, 2.0, 0.5, {"ms_per_update": 30.0}),
            Run(100, 4.0, 1.0, {"ms_per_update": 20.0})]
    figures = summarise(runs, "env_steps")
    assert figures["env_steps_per_s"] == {"median": 50.0, "min": 25.0, "max": 100.0, "runs": [100.0, 50.0, 25.0]}
    assert figures["env_steps_per_cpu_s"]["median"] == 200.0 and figures["ms_per_update"]["median"] == 20.0
    combined = combine([{"players": 2, "rate": 1.0, "phase": {"ms": 3.0}, "ok": True},
                        {"players": 2, "rate": 3.0, "phase": {"ms": 1.0}, "ok": True}], plain=("players",))
    assert combined["players"] == 2 and combined["ok"] is True
    assert combined["rate"]["median"] == 2.0 and combined["phase"]["ms"] == {"median": 2.0, "min": 1.0, "max": 3.0,
                                                                             "runs": [3.0, 1.0]}
