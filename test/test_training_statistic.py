"""The paper's driving statistic from a training log (evaluation/training_statistic.py, dynenv-eval training-best):
the expected values are worked out by hand below."""
from __future__ import annotations

from pathlib import Path

import pytest

from dynenv_ros.evaluation.cli import main
from dynenv_ros.evaluation.training_statistic import best_moving_average, training_statistic


def _log(path: Path, rows: list[tuple[int, str, str]]) -> Path:
    lines = ["env_steps,update,wall_seconds,name,value"]
    lines += [f"{step},{k},{k}.0,{name},{value}" for k, (step, name, value) in enumerate(rows)]
    path.write_text("\n".join(lines) + "\n")
    return path


def test_the_best_moving_average_and_where_it_ends():
    # windows of 2 over 1, 5, 3, 9, 2: 3, 4, 6, 5.5 -> 6, ending at the 4th value (step 400)
    assert best_moving_average([100, 200, 300, 400, 500], [1.0, 5.0, 3.0, 9.0, 2.0], 2) == (6.0, 400)
    # a window of one is the maximum; a window of all values is the mean
    assert best_moving_average([1, 2, 3], [2.0, -1.0, 7.0], 1) == (7.0, 3)
    assert best_moving_average([1, 2, 3], [2.0, -1.0, 8.0], 3) == (3.0, 3)
    with pytest.raises(ValueError, match="fewer than the window"):
        best_moving_average([1], [1.0], 2)
    with pytest.raises(ValueError, match="window must be a positive integer"):
        best_moving_average([1, 2], [1.0, 2.0], 0)


def test_a_runs_log_other_metrics_a_cut_row_and_a_relogged_step(tmp_path):
    rows = [(100, "episode/return", "1"), (100, "train/entropy", "50"), (200, "episode/return", "5"),
            (300, "episode/return", "3"), (400, "episode/return", "9"),
            (300, "episode/return", "-7"),      # resumed from the checkpoint at 200: step 300 again, later wins
            (500, "episode/return", "2")]
    path = _log(tmp_path / "metrics.csv", rows)
    with open(path, "a") as handle:
        handle.write("600,9,9.0,episode/return")      # a row cut short by a kill (no value)
    # steps 100..500: 1, 5, -7, 9, 2 -> windows of 2: 3, -1, 1, 5.5 -> 5.5 ending at step 500
    result = training_statistic(tmp_path, window=2)
    assert (result["best"], result["at_env_steps"], result["windows"]) == (5.5, 500, 5)
    assert training_statistic(path, "train/entropy", window=1)["best"] == 50.0
    with pytest.raises(ValueError, match="no metric 'episode/home' logged"):
        training_statistic(path, "episode/home")
    with pytest.raises(ValueError, match="no training log"):
        training_statistic(tmp_path / "elsewhere")


def test_the_cli_prints_each_run_and_their_mean_and_refuses_in_one_line(tmp_path, capsys):
    for name, values in (("a", [1, 3]), ("b", [5, 9])):
        (tmp_path / name).mkdir()
        _log(tmp_path / name / "metrics.csv", [(100 * (k + 1), "episode/return", str(v)) for k, v in
                                               enumerate(values)])
    assert main(["training-best", str(tmp_path / "a"), str(tmp_path / "b"), "--window", "1"]) == 0
    out = capsys.readouterr().out
    assert "best 1-window moving average of episode/return 3 (at 200 env steps" in out
    assert "episode/return 9 (at 200 env steps" in out
    assert "mean over 2 runs: 6 ± 4.2 (sd)" in out        # (3 + 9) / 2, sd sqrt(18)
    assert main(["training-best", str(tmp_path / "a"), "--window", "3"]) == 2
    err = capsys.readouterr().err
    assert "fewer than the window of 3" in err and len(err.strip().splitlines()) == 1
