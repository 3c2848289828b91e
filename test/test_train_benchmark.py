"""benchmarks/train.py beside the simulation: an async preset's figures carry the one-world simulation rate measured
in the same run (``dynenv-bench sim --observation padded``'s) and the ratio of the two, repetition by repetition."""
import os

import pytest

from benchmarks.sim import one_world_padded
from benchmarks.timing import stat
from benchmarks.train import sim_lines, sim_ratio


def _sim_run(rate: float, cpu_rate: float) -> dict:
    """A repetition's sim figures as ``one_world_padded`` gives them (one run: each rate a stat of one value)."""
    return {"measures": "robocup 2v2: the whole env step, padded observations", "steps": 2000,
            "env_steps_per_s": stat([rate]), "env_steps_per_cpu_s": stat([cpu_rate])}


def test_the_ratio_is_taken_repetition_by_repetition():
    """Three repetitions: 400, 600 and 500 env steps/s of training against 1,600, 1,500 and 2,000 of one world give
    0.25, 0.40 and 0.25 — median 0.25, range 0.25–0.40 (the ratio of the medians, 500 / 1,600, would be 0.3125)."""
    train = [{"env_steps_per_s": 400.0}, {"env_steps_per_s": 600.0}, {"env_steps_per_s": 500.0}]
    sims = [_sim_run(1600.0, 1590.0), _sim_run(1500.0, 1480.0), _sim_run(2000.0, 1990.0)]
    figures = sim_ratio(train, sims)
    ratio = figures["ratio_to_one_world_sim"]
    assert ratio["runs"] == [0.25, 0.4, 0.25] and (ratio["median"], ratio["min"], ratio["max"]) == (0.25, 0.25, 0.4)
    sim = figures["one_world_sim"]
    assert sim["env_steps_per_s"]["runs"] == [1600.0, 1500.0, 2000.0] and sim["env_steps_per_s"]["median"] == 1600.0
    assert sim["env_steps_per_cpu_s"]["median"] == 1590.0 and sim["steps"] == 2000
    lines = sim_lines(figures, "async")
    assert "1,600 [1,500–2,000] env steps/s" in lines[0] and "padded observations" in lines[0]
    assert lines[1].startswith("async / one-world simulation env steps per second: 0.25")
    with pytest.raises(ValueError, match="3 training runs against 2"):
        sim_ratio(train, sims[:2])


def test_the_one_world_rate_is_the_sim_suites_padded_2v2_on_one_core_and_the_cores_come_back():
    allowed = os.sched_getaffinity(0)
    figures = one_world_padded(20)
    assert os.sched_getaffinity(0) == allowed
    assert figures["observation"] == "padded" and figures["players_per_team"] == 2 and figures["envs"] == 1
    assert figures["cores"] == 1 and figures["noise"] == "realistic" and figures["steps"] == 20
    assert figures["env_steps_per_s"]["median"] > 0 and len(figures["env_steps_per_s"]["runs"]) == 1
