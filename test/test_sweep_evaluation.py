"""dynenv-sweep's evaluation settings: --greedy reaches every run's evaluation (the best-method group of docs/results.md
is played greedily), and a sweep refuses to mix its runs with ones evaluated otherwise in the same folder."""
from __future__ import annotations

import json
from pathlib import Path

from dynenv_ros.experiments.sweep import _evaluate, evaluated_otherwise, main
from dynenv_ros.learning.config import load_config
from dynenv_ros.learning.train_cli import preset_path

ROOT = Path(__file__).resolve().parent.parent
DRIVING_POLICY = ROOT / "policy_node" / "pretrained" / "driving" / "policy.safetensors"


def test_greedy_reaches_the_policys_evaluation_and_not_a_reference_driver():
    cfg = load_config(preset_path("driving_quick"), ["episode_seconds=5"])
    settings = {"episodes": 1, "opponent": "random", "seeds": [0], "greedy": True}
    result = _evaluate(cfg, DRIVING_POLICY, settings)
    assert result["settings"]["greedy"] is True and result["evaluated"]["greedy"] is True
    reference = _evaluate(cfg, "random", settings)            # a random driver has no most likely action
    assert reference["settings"]["greedy"] is False


def test_an_evaluation_made_otherwise_is_named():
    evaluation = {"episodes": 10, "opponent": "random", "seeds": [100, 101], "greedy": False}
    alike = {"settings": {"episodes": 10, "seeds": [100, 101], "greedy": False}, "opponent": {"spec": "random"}}
    assert evaluated_otherwise(alike, evaluation) == ""
    other = {"settings": {"episodes": 4, "seeds": [100, 101], "greedy": True}, "opponent": {"spec": "perceiving"}}
    assert evaluated_otherwise(other, evaluation) == ("episodes 4, not 10; greedy True, not False; "
                                                      "opponent 'perceiving', not 'random'")
    driving = {"scenario": "driving", "settings": {"episodes": 10, "seeds": [100, 101], "greedy": False}}
    assert evaluated_otherwise(driving, evaluation) == ""      # driving has no opponent


def test_a_sweep_over_runs_evaluated_otherwise_is_refused_before_anything_runs(tmp_path, capsys):
    out = tmp_path / "sweep"
    (out / "baseline_s0").mkdir(parents=True)
    done = {"format": "dynenv_eval/1", "settings": {"episodes": 1, "seeds": [0], "greedy": False},
            "opponent": {"spec": "random"}, "per_seed": []}
    (out / "baseline_s0" / "eval.json").write_text(json.dumps(done))
    code = main(["--config", "quick", "--variants", "baseline", "--seeds", "0", "--eval-episodes", "1",
                 "--eval-seeds", "0", "--greedy", "--out", str(out)])
    assert code == 2
    assert "was evaluated with other settings (greedy False, not True)" in capsys.readouterr().err
