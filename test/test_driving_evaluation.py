"""dynenv-eval --scenario driving: a driving checkpoint, random and scripted drivers over the same seeded episodes,
the JSON result (reward by term, cars home, crashes) that ``dynenv-eval compare`` reads, and the refusals."""
from __future__ import annotations

import json

import pytest
import torch

from dynenv_ros.agent.checkpoint import save_policy
from dynenv_ros.agent.network import DynEnvAgent
from dynenv_ros.learning.driving_evaluation import SEED_METRICS, evaluate_driving, format_driving_table
from dynenv_ros.learning.eval_cli import main
from dynenv_ros.learning.evaluation import FORMAT, load_evaluation, seed_values, write_json

SHORT = {"episode_seconds": 3.0}


def _policy(tmp_path, mode="discrete", scenario="driving"):
    torch.manual_seed(0)
    agent = DynEnvAgent(16, scenario=scenario, action_mode=mode) if scenario == "driving" else DynEnvAgent(16)
    path = tmp_path / f"{scenario}_{mode}.safetensors"
    save_policy(agent, str(path))
    return path


@pytest.mark.parametrize("driver", ["random", "scripted"])
def test_baseline_drivers_give_a_result_compare_reads(tmp_path, driver):
    result = evaluate_driving(driver, episodes=2, seeds=[0, 1], perception="none", env_config=SHORT)
    assert result["format"] == FORMAT and result["scenario"] == "driving"
    assert len(result["episodes"]) == 4 and len(result["per_seed"]) == 2
    for row in result["per_seed"]:
        assert set(SEED_METRICS) <= set(row)
        assert 0.0 <= row["home_rate"] <= 1.0 and 0.0 <= row["crash_rate"] <= 1.0
        assert row["total"] == pytest.approx(row["primary"] + row["rule"] + row["auxiliary"] + row["observation"])
    path = tmp_path / f"{driver}.json"
    write_json(result, path)
    assert seed_values(load_evaluation(path), "total") == [r["total"] for r in result["per_seed"]]
    assert "| mean ± sd |" in format_driving_table(result)


def test_drivers_meet_the_same_episodes_and_scripted_drives_better_than_random():
    scripted = evaluate_driving("scripted", episodes=1, seeds=[0, 1], perception="none",
                                env_config={"episode_seconds": 8.0})
    random = evaluate_driving("random", episodes=1, seeds=[0, 1], perception="none",
                              env_config={"episode_seconds": 8.0})
    assert [r["env_seed"] for r in scripted["episodes"]] == [r["env_seed"] for r in random["episodes"]]
    assert scripted["summary"]["auxiliary"]["mean"] > random["summary"]["auxiliary"]["mean"] + 1.0


@pytest.mark.parametrize("mode", ["discrete", "continuous"])
def test_a_driving_checkpoint_drives_every_car(tmp_path, mode):
    path = _policy(tmp_path, mode)
    result = evaluate_driving(str(path), episodes=1, seeds=[3], n_cars=3, perception="realistic", env_config=SHORT)
    assert result["settings"]["action_mode"] == mode and result["evaluated"]["kind"] == "checkpoint"
    assert len(result["episodes"][0]["cars"]) == 3
    again = evaluate_driving(str(path), episodes=1, seeds=[3], n_cars=3, perception="realistic", env_config=SHORT)
    assert again["per_seed"] == result["per_seed"]               # seeded: the same episode and the same draws
    with pytest.raises(ValueError, match="action mode"):
        evaluate_driving(str(path), episodes=1, seeds=[0], action_mode="continuous" if mode == "discrete" else
                         "discrete", env_config=SHORT)


def test_cli_driving_writes_json_and_compare_runs(tmp_path, capsys):
    out_random, out_policy = tmp_path / "random.json", tmp_path / "policy.json"
    common = ["--scenario", "driving", "--episodes", "1", "--seeds", "0", "1", "--perception", "none",
              "--episode-seconds", "3", "--quiet"]
    assert main(["random", *common, "--out", str(out_random)]) == 0
    assert main([str(_policy(tmp_path)), *common, "--out", str(out_policy)]) == 0
    assert json.loads(out_policy.read_text())["scenario"] == "driving"
    assert main(["compare", str(out_random), str(out_policy), "--metric", "total", "--draws", "100", "--tune",
                 "100"]) == 0
    assert "BEST on total" in capsys.readouterr().out


def test_cli_refusals(tmp_path, capsys):
    assert main(["random", "--scenario", "driving", "--opponent", "scripted"]) == 2
    assert "no opponent" in capsys.readouterr().err
    assert main([str(_policy(tmp_path)), "--episodes", "1"]) == 2                  # a driving policy, soccer eval
    assert "--scenario driving" in capsys.readouterr().err
    soccer = _policy(tmp_path, scenario="soccer")
    assert main([str(soccer), "--scenario", "driving", "--episodes", "1", "--seeds", "0"]) == 2
    assert "soccer policy" in capsys.readouterr().err
    assert main(["random", "--action-mode", "continuous"]) == 2
    assert "--scenario driving" in capsys.readouterr().err


def test_cli_refuses_the_other_scenarios_flags(capsys):
    """A flag that means nothing for the chosen scenario is refused, not silently ignored."""
    for argv, flag in ((["random", "--scenario", "driving", "--sides", "a"], "--sides"),
                       (["random", "--scenario", "driving", "--players-per-team", "3"], "--players-per-team"),
                       (["random", "--cars", "3"], "--cars")):
        assert main(argv) == 2
        err = capsys.readouterr().err
        assert flag in err and "only" in err
