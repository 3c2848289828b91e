"""dynenv-sweep --scratch: a run killed mid-way is resumed from its checkpoint when the sweep runs again, not
started over (a session's end or a reboot otherwise throws away up to a whole run)."""
from __future__ import annotations

import csv
import subprocess
import sys
from pathlib import Path

import numpy as np
from safetensors.numpy import load

from dynenv_ros.experiments.sweep import train_and_evaluate
from dynenv_ros.learning.config import load_config
from dynenv_ros.learning.train_cli import preset_path

ROOT = Path(__file__).resolve().parent.parent
TINY = ["num_envs=2", "players_per_team=1", "perception=none", "episode_seconds=10", "rollout_length=8"]


def _rows(run_dir: Path) -> list[tuple[str, ...]]:
    with open(run_dir / "metrics.csv") as handle:
        return [tuple(row.values()) for row in csv.DictReader(handle)]


def test_a_scratch_run_with_a_checkpoint_is_resumed_not_restarted(tmp_path):
    scratch = tmp_path / "scratch"
    run_dir = scratch / "baseline_s0"
    # The first part of the run, as a sweep killed after its first checkpoint leaves it. Its seed differs from the
    # sweep's, so a run started over would log other numbers for the same steps.
    done = subprocess.run([sys.executable, "-m", "dynenv_ros.learning.train_cli", "--config", "quick", "--run-dir",
                           str(run_dir), "--no-progress", "--set", "variant=baseline", "--set", "seed=1",
                           *[f"--set={item}" for item in TINY], "--set", "total_env_steps=32"],
                          cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    first = _rows(run_dir)
    cfg = load_config(preset_path("quick"), ["variant=baseline", "seed=0", *TINY, "total_env_steps=64"])
    evaluation = {"episodes": 1, "opponent": "random", "seeds": [0]}
    result = train_and_evaluate(cfg.to_dict(), "baseline_s0", evaluation, scratch=str(scratch))
    assert result["summary"]["env_steps"] >= 64
    rows = _rows(run_dir)
    assert rows[:len(first)] == first and len(rows) > len(first)    # the first part's log kept
    first_part_end = max(int(row[0]) for row in first)
    assert min(int(row[0]) for row in rows[len(first):]) > first_part_end   # and the run went on from there
    assert max(int(row[0]) for row in rows) >= 64 and (run_dir / "policy.safetensors").is_file()
    assert set(result["files"]) >= {"config.json", "summary.json", "metrics.csv", "policy.safetensors"}
    # A run of the sweep's config started over ends elsewhere: the resumed one carries the first part's training.
    fresh = train_and_evaluate(cfg.to_dict(), "baseline_s0", evaluation, scratch=str(tmp_path / "fresh"))
    again = train_and_evaluate(cfg.to_dict(), "baseline_s0", evaluation, scratch=str(tmp_path / "again"))
    assert _same_weights(again, fresh)                  # training is deterministic per seed ...
    assert not _same_weights(fresh, result)             # ... so the resumed run's weights tell it went on


def _same_weights(one: dict, other: dict) -> bool:
    first, second = load(one["files"]["policy.safetensors"]), load(other["files"]["policy.safetensors"])
    return first.keys() == second.keys() and all(np.array_equal(first[k], second[k]) for k in first)


def test_a_scratch_folder_without_a_checkpoint_starts_over(tmp_path):
    scratch = tmp_path / "scratch"
    (scratch / "baseline_s0").mkdir(parents=True)
    (scratch / "baseline_s0" / "config.json").write_text("{}")      # killed before its first checkpoint
    cfg = load_config(preset_path("quick"), ["variant=baseline", "seed=0", *TINY, "total_env_steps=32"])
    result = train_and_evaluate(cfg.to_dict(), "baseline_s0", {"episodes": 1, "opponent": "random", "seeds": [0]},
                                scratch=str(scratch))
    assert result["summary"]["env_steps"] >= 32


def test_scratch_with_a_cluster_address_is_refused_in_one_line(tmp_path):
    done = subprocess.run([sys.executable, "-m", "dynenv_ros.experiments.sweep", "--config", "quick", "--variants",
                           "baseline", "--seeds", "0", "--out", str(tmp_path / "out"), "--scratch",
                           str(tmp_path / "s"), "--ray-address", "127.0.0.1:1"],
                          cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert done.returncode == 2
    assert done.stderr.strip().count("\n") == 0 and "--scratch" in done.stderr, done.stderr
