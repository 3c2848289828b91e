"""dynenv-eval --scenario driving: a driving checkpoint, random and scripted drivers over the same seeded episodes,
the JSON result (reward by term, cars home, crashes) that ``dynenv-eval compare`` reads, and the refusals."""
from __future__ import annotations

import json

import pytest
import torch

from dynenv_ros.agent.checkpoint import save_policy
from dynenv_ros.agent.network import DynEnvAgent
from dynenv_ros.evaluation.best import seed_values
from dynenv_ros.evaluation.cli import main
from dynenv_ros.evaluation.driving import SEED_METRICS, evaluate_driving, format_driving_table
from dynenv_ros.evaluation.results import FORMAT, load_evaluation, write_json

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


def test_merge_makes_each_run_one_unit_and_refuses_what_does_not_fit(tmp_path, capsys):
    """dynenv-eval merge: one row per input file, each the mean of that file's per-seed numbers; compare reads it."""
    common = ["--scenario", "driving", "--episodes", "1", "--perception", "none", "--episode-seconds", "3", "--quiet"]
    runs = []
    for k in range(3):                           # three "training runs", each evaluated on the same two seeds
        out = tmp_path / f"run{k}.json"
        torch.manual_seed(k)
        policy = tmp_path / f"policy{k}.safetensors"
        save_policy(DynEnvAgent(16, scenario="driving"), str(policy))
        assert main([str(policy), *common, "--seeds", "0", "1", "--out", str(out)]) == 0
        runs.append(out)
    merged_path = tmp_path / "merged.json"
    assert main(["merge", *map(str, runs), "--out", str(merged_path)]) == 0
    merged = load_evaluation(merged_path)
    assert [row["seed"] for row in merged["per_seed"]] == [0, 1, 2]
    for row, path in zip(merged["per_seed"], runs):
        seeds = json.loads(path.read_text())["per_seed"]
        assert row["unit"] == str(path) and row["episodes"] == 2
        for metric in ("total", "home_rate", "crash_rate", "auxiliary"):
            assert row[metric] == pytest.approx(sum(s[metric] for s in seeds) / len(seeds))
    assert len(merged["episodes"]) == 6 and merged["summary"]["total"]["n"] == 3
    capsys.readouterr()
    assert main(["compare", str(runs[0]), str(merged_path), "--draws", "100", "--tune", "100"]) == 0
    assert "(n=3) vs run0 (n=2)" in capsys.readouterr().out

    other = tmp_path / "other_seeds.json"        # evaluated on other seeds: not the same settings
    assert main(["random", *common, "--seeds", "5", "--out", str(other)]) == 0
    assert main(["merge", str(runs[0]), str(other), "--out", str(tmp_path / "bad.json")]) == 2
    error = capsys.readouterr().err
    assert "settings differ" in error and "seeds" in error
    assert not (tmp_path / "bad.json").exists()
    (tmp_path / "broken.json").write_text("{not json")
    assert main(["merge", str(runs[0]), str(tmp_path / "broken.json"), "--out", str(tmp_path / "bad.json")]) == 2
    assert "not readable JSON" in capsys.readouterr().err
    assert main(["merge", str(runs[0]), "--out", str(tmp_path / "no_folder" / "m.json")]) == 2
    (tmp_path / "a_folder").mkdir()
    assert main(["merge", str(runs[0]), "--out", str(tmp_path / "a_folder")]) == 2       # a folder, not a file
    assert "it is a folder" in capsys.readouterr().err and not (tmp_path / "a_folder.tmp").exists()
