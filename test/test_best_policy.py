"""best_policy_window: a run keeps the policy at the peak of its training curve — the best moving average of the
logged episode returns, which dynenv-eval training-best reads from the same metrics.csv — and a resumed run keeps
tracking it from where the log and the kept file left off."""
from __future__ import annotations

import json
import math

import pytest

from dynenv_ros.evaluation.training_statistic import training_statistic
from dynenv_ros.learning.run import checkpoints
from dynenv_ros.learning.run.best_policy import BEST_POLICY, BestPolicy
from dynenv_ros.learning.config import ConfigError, TrainConfig
from dynenv_ros.learning.train_cli import main

TINY = ["--set", "num_envs=1", "--set", "players_per_team=1", "--set", "backend=inprocess",
        "--set", "rollout_length=4", "--set", "ltp_horizon=4", "--set", "episode_seconds=2",
        "--set", "log_every_updates=1", "--set", "best_policy_window=2", "--set", "max_minutes=5"]


def test_the_tracker_keeps_each_new_peak_of_the_moving_average():
    best = BestPolicy(2)
    # window returns 1, 3, 2, 5, 0, 6: moving averages of 2 are 2, 2.5, 3.5, 2.5, 3 — peaks at 2, 2.5 and 3.5
    assert [best.observe(v) for v in (1.0, 3.0, 2.0, 5.0, 0.0, 6.0)] == [None, 2.0, 2.5, 3.5, None, None]
    assert best.best == 3.5
    assert best.observe(float("nan")) is None and list(best.recent) == [0.0, 6.0]    # a window without a number
    with pytest.raises(ValueError, match="window must be a positive integer"):
        BestPolicy(0)


def test_the_window_is_checked_with_the_config():
    with pytest.raises(ConfigError, match="best_policy_window: must be in 1..100000, got 0"):
        TrainConfig(best_policy_window=0)
    assert TrainConfig().best_policy_window is None          # off by default: only the last policy
    from dynenv_ros.learning.messages.message_trainer import MessageTrainer
    with pytest.raises(ConfigError, match="best_policy_window: .*the trainer node and --from-bag do not"):
        MessageTrainer(TrainConfig(algorithm="ppo", best_policy_window=10), "unused-run-dir")


def test_a_run_keeps_the_policy_where_training_best_finds_the_peak_and_a_resume_goes_on(tmp_path):
    run = tmp_path / "run"
    assert main(["--config", "quick", "--run-dir", str(run), "--no-progress", *TINY,
                 "--set", "total_env_steps=64"]) == 0
    statistic = training_statistic(run, window=2)
    assert statistic["windows"] >= 3, statistic                 # episodes of 2 s finish within the run
    _, meta = checkpoints.load_policy(run / BEST_POLICY)
    assert meta["env_steps"] == statistic["at_env_steps"]
    assert meta["best_window"] == 2 and math.isclose(meta["best_moving_average"], statistic["best"], rel_tol=1e-9)
    assert meta["env_steps"] <= json.loads((run / "summary.json").read_text())["env_steps"]

    # resumed: the tracker starts from the log's last windows and the kept file's peak, so after more training the
    # file is still the policy at the peak of the whole log
    tracker = BestPolicy.resume(run, 2, 64)
    assert tracker.best == meta["best_moving_average"] and len(tracker.recent) == 2
    assert main(["--resume", str(run), "--no-progress", "--set", "total_env_steps=128"]) == 0
    statistic = training_statistic(run, window=2)
    _, meta = checkpoints.load_policy(run / BEST_POLICY)
    assert meta["env_steps"] == statistic["at_env_steps"]
    assert math.isclose(meta["best_moving_average"], statistic["best"], rel_tol=1e-9)


def test_a_damaged_or_foreign_kept_file_does_not_stop_a_resume(tmp_path):
    """A kept file cut short by a full disk, or kept over another window, is not a peak to beat: the resumed run
    tracks from scratch and replaces it at its next peak (the training checkpoint, not this file, is what resumes)."""
    from dynenv_ros.learning.run.best_policy import kept_average
    path = tmp_path / BEST_POLICY
    path.write_bytes(b"\x10\x00\x00\x00\x00\x00\x00\x00{not json")
    assert BestPolicy.resume(tmp_path, 3, 0).best == -math.inf and kept_average(path, 3) == -math.inf
    assert kept_average(tmp_path / "absent.safetensors", 3) == -math.inf
