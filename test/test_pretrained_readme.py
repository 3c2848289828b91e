"""policy_node/pretrained/README.md is what tools/pretrained_readme.py makes of the files beside it (so it cannot
drift from the policy), names the policy file's sha256, and the generator refuses the evaluation of another policy."""
from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
from tool_scripts import load_tool

from dynenv_ros.agent.checkpoint import sha256


@pytest.fixture(scope="module")
def tool():
    return load_tool("pretrained_readme")


@pytest.fixture(scope="module")
def folder(tool):
    return tool.ROOT / tool.FOLDER


SOCCER_FOLDERS = [Path("policy_node/pretrained"), Path("docs/results_data/issue26/shipped_2fd24e79"),
                  Path("docs/results_data/issue39/shipped_ca882145")]
IDS = ["shipped", "archived_first", "archived_league"]


@pytest.mark.parametrize("relative", SOCCER_FOLDERS, ids=IDS)
def test_the_committed_readme_is_what_the_files_give(tool, relative):
    try:
        expected = tool.render(tool.ROOT, relative)
    except tool.GitUnknown as error:         # a clone without the history the README's fix check reads
        pytest.skip(str(error))
    assert (tool.ROOT / relative / "README.md").read_text() == expected, \
        "run .venv/bin/python tools/pretrained_readme.py"


@pytest.mark.parametrize("relative", SOCCER_FOLDERS, ids=IDS)
def test_the_readme_names_the_policy_files_sha256_and_its_evaluations_are_of_that_file(tool, relative):
    here = tool.ROOT / relative
    digest, text = sha256(here / tool.POLICY), (here / "README.md").read_text()
    assert f"sha256 `{digest}`" in text
    evaluations = sorted((here / tool.EVAL_DIR).glob("*.json"))
    assert {path.stem for path in evaluations} >= {"vs_random", "vs_scripted", "vs_perceiving"}
    for path in evaluations:
        assert json.loads(path.read_text())["evaluated"]["sha256"] == digest, path
        assert f".venv/bin/dynenv-eval {relative}/policy.safetensors " in text
        assert f"--out {relative}/eval/{path.name}" in text


def test_the_shipped_readme_plays_on_validation_and_says_which_of_issue_39s_bars_it_meets(tool, folder):
    """The shipped policy (issue 39's league_privileged_5v5_s0 at its end, +400,128 env steps) is evaluated on the
    validation split, and its two test-ledger rows, as this very file, give the bars: docs/results.md reports
    +0.235 (+0.158 to +0.313; 146 wins, 192 draws, 62 losses in 400 games) against perceiving and +0.103 (+0.028 to
    +0.183; 114 / 203 / 83) against the ground-truth team; no 5v5 test row."""
    text = (folder / "README.md").read_text()
    assert "## How it plays (validation split, seeds 10,000–10,024:" in text
    assert "--split validation --num-seeds 25" in text and "--seeds" not in text
    assert "trained in 7 stages and 5 runs" in text
    # league_anchor_s0_271k.safetensors holds weights alone: the recipe comes from its committed twin's header
    assert ("from `docs/results_data/issue39/policies/league_anchor_s0_271k.safetensors` (its weights alone are in "
            "that file; the header of `docs/results_data/issue39/shipped_ca882145/policy.safetensors`, the same "
            "weights, counts 270,592 env steps)") in text
    assert text.count("| this file |") == 2 and "the training checkpoint it was written from" not in text
    assert ("- **met** — against `perceiving` at 2v2: 146 wins, 192 draws, 62 losses in 400 games, +0.23 goals a game "
            "(+0.16 to +0.31), the interval above 0, and at least twice as many wins as losses.") in text
    assert ("- **met** — against the ground-truth `scripted` team at 2v2: 114 wins, 203 draws, 83 losses in 400 "
            "games, +0.10 goals a game (+0.03 to +0.18), the interval above 0.") in text
    assert "- **not tried** — at 5v5 against `perceiving`: no test-split row." in text


def test_the_archived_league_readme_keeps_its_ledger_rows_and_bars(tool):
    """The league policy shipped 29-30 Nov (league_anchor_s0 at +270,592 env steps) keeps its README: its test-ledger
    rows — two as the training checkpoint it was written from, one as the committed policy file with its weights —
    give the bars: docs/results.md reports +0.21 (+0.04 to +0.38, 34 wins to 17 losses) against perceiving, +0.09
    (−0.09 to +0.28) against the ground-truth team, −0.09 (−0.24 to +0.06) at 5v5."""
    text = (tool.ROOT / SOCCER_FOLDERS[2] / "README.md").read_text()
    assert text.startswith("# The league policy shipped before the privileged league's")
    assert "trained in 5 stages and 3 runs" in text
    assert "evaluated as the training checkpoint this file was written from" in text
    assert text.count("| the training checkpoint it was written from |") == 2
    assert text.count("| `league_anchor_s0_271k.safetensors` |") == 1
    assert ("- **met** — against `perceiving` at 2v2: 34 wins, 49 draws, 17 losses in 100 games, +0.21 goals a game "
            "(+0.04 to +0.38), the interval above 0, and at least twice as many wins as losses.") in text
    assert ("- **not met** — against the ground-truth `scripted` team at 2v2: 29 wins, 47 draws, 24 losses in 100 "
            "games, +0.09 goals a game (-0.09 to +0.28), level: the interval includes 0.") in text
    assert ("- **not met** — at 5v5 against `perceiving`: 24 wins, 43 draws, 33 losses in 100 games, -0.09 goals a "
            "game (-0.24 to +0.06), level: the interval includes 0.") in text


def test_the_archived_readme_says_what_it_is_and_plays_its_own_files(tool):
    relative = SOCCER_FOLDERS[1]
    text = (tool.ROOT / relative / "README.md").read_text()
    assert text.startswith("# The soccer policy shipped before the league policy")
    assert f'make run ARGS="--set team_a={relative}/policy.onnx"' in text
    assert "## How it plays (seeds 100–104: train split" in text
    assert "No test-split evaluation of this policy yet." in text


def test_an_evaluation_of_another_policy_is_refused(tool, folder, tmp_path):
    copy = tmp_path / tool.FOLDER
    shutil.copytree(folder, copy)
    path = copy / tool.EVAL_DIR / "vs_random.json"
    result = json.loads(path.read_text())
    result["evaluated"]["sha256"] = "0" * 64
    path.write_text(json.dumps(result))
    with pytest.raises(tool.ReadmeError, match=r"vs_random.json evaluates another policy: its sha256 is 0{64}"):
        tool.render(root=tmp_path)


def test_check_mode_reports_a_stale_readme(tool, folder, tmp_path, monkeypatch, capsys):
    copy = tmp_path / tool.FOLDER
    shutil.copytree(folder, copy)
    monkeypatch.setattr(tool, "render", lambda *args: "something else\n")
    monkeypatch.setattr(tool, "ROOT", tmp_path)
    assert tool.main(["--check"]) == 1
    assert "is not what the files give" in capsys.readouterr().err


def test_training_stages_must_give_the_policys_training_config(tool, tmp_path):
    """train_stages.json (a run trained on after a change of settings) is checked: its stages, applied in order,
    must give exactly the training config in the policy file's header; a stage left out, or a first stage that
    does not start a run, is refused."""
    from dynenv_ros.learning.config import load_config
    config = load_config(tool.ROOT / tool.PRESETS / "async_teacher.yaml",
                         ["opponent=perceiving", "total_env_steps=1000000", "seed=3"]).to_dict()
    stages = [{"train": ["--config", "async_teacher", "--seed", "3", "--set", "total_env_steps=700000"], "why": "a"},
              {"train": ["--resume", "run", "--set", "opponent=perceiving", "--set", "total_env_steps=1000000"],
               "why": "b"}]
    here = tmp_path / "pretrained"
    here.mkdir()
    assert tool.training_stages(here, config) is None                  # no file: one command, as before
    (here / "train_stages.json").write_text(json.dumps({"stages": stages}))
    assert [stage["why"] for stage in tool.training_stages(here, config)] == ["a", "b"]
    # a policy trained before a setting existed (best_policy_window, added 28 Nov 2026) lacks it in its header: the
    # setting's default, which keeps the old behaviour, stands in for it
    older = {k: v for k, v in config.items() if k != "best_policy_window"}
    assert [stage["why"] for stage in tool.training_stages(here, older)] == ["a", "b"]
    (here / "train_stages.json").write_text(json.dumps({"stages": stages[:1]}))
    with pytest.raises(tool.ReadmeError, match="do not give the training config"):
        tool.training_stages(here, config)
    (here / "train_stages.json").write_text(json.dumps({"stages": stages[::-1]}))
    with pytest.raises(tool.ReadmeError, match="the first stage must start a run"):
        tool.training_stages(here, config)


def test_a_later_run_must_start_from_a_policy_file_the_stages_before_it_made(tool, tmp_path):
    """train_stages.json may start a new run from the policy the stages before it made (init_policy): the file
    must be there and its header's training config must be what those stages give; the env steps and minutes of
    the runs add up. A new run without an init_policy, or from a file trained otherwise, is refused."""
    from dynenv_ros.agent.checkpoint import save_policy
    from dynenv_ros.agent.network import DynEnvAgent
    from dynenv_ros.learning.config import load_config
    first = load_config(tool.ROOT / tool.PRESETS / "async_teacher.yaml", ["total_env_steps=1000", "seed=3"]).to_dict()
    start = tmp_path / "start.safetensors"
    save_policy(DynEnvAgent(8), start, {"config": first, "env_steps": 1000, "wall_seconds": 60.0})
    config = load_config(tool.ROOT / tool.PRESETS / "league.yaml", [f"init_policy={start}", "seed=0"]).to_dict()
    stages = [{"train": ["--config", "async_teacher", "--seed", "3", "--set", "total_env_steps=700"], "why": "a"},
              {"train": ["--resume", "run", "--set", "total_env_steps=1000"], "why": "b"},
              {"train": ["--config", "league", "--seed", "0", "--set", f"init_policy={start}"], "why": "c"}]
    here = tmp_path / "pretrained"
    here.mkdir()
    (here / "train_stages.json").write_text(json.dumps({"stages": stages}))
    runs = tool.stage_runs(here, config)
    assert [[stage["why"] for stage in run.stages] for run in runs] == [["a", "b"], ["c"]]
    assert runs[0].start is None and runs[1].start == start and runs[1].start_meta["env_steps"] == 1000
    line = tool._budget_line({"env_steps": 500, "updates": 2, "episodes": 3, "wall_seconds": 120.0}, "on cpu", runs)
    assert line.startswith("- **1,500 env steps** in all, over 2 runs (1,000 + 500), in 3 minutes; the last run's")
    save_policy(DynEnvAgent(8), start, {"config": {**first, "learning_rate": 1.0}, "env_steps": 1000})
    with pytest.raises(tool.ReadmeError, match="was not trained with the config the stages before it give"):
        tool.stage_runs(here, config)
    (here / "train_stages.json").write_text(json.dumps({"stages": [*stages[:2], {"train": ["--config", "quick"]}]}))
    with pytest.raises(tool.ReadmeError, match="stage 3 starts a new run without an init_policy"):
        tool.stage_runs(here, load_config(tool.ROOT / tool.PRESETS / "quick.yaml").to_dict())
    start.unlink()
    (here / "train_stages.json").write_text(json.dumps({"stages": stages}))
    with pytest.raises(tool.ReadmeError, match="stage 3 starts from .*start.safetensors, which is not in the"):
        tool.stage_runs(here, config)


# -- the shipped driving policy (policy_node/pretrained/driving) ---------------------------------------------------
@pytest.fixture(scope="module")
def driving_folder(tool):
    return tool.ROOT / tool.DRIVING_FOLDER


def test_the_committed_driving_readme_is_what_its_files_give(tool, driving_folder):
    assert (driving_folder / "README.md").read_text() == tool.render(tool.ROOT, tool.DRIVING_FOLDER), \
        "run .venv/bin/python tools/pretrained_readme.py"


def test_the_driving_readme_names_its_policy_and_the_paper_statistic_it_is_not(tool, driving_folder):
    digest, text = sha256(driving_folder / tool.POLICY), (driving_folder / "README.md").read_text()
    assert f"sha256 `{digest}`" in text
    evaluation = json.loads((driving_folder / tool.EVAL_DIR / "policy.json").read_text())
    assert evaluation["evaluated"]["sha256"] == digest
    assert "--out policy_node/pretrained/driving/eval/policy.json" in text
    assert "--out policy_node/pretrained/driving/eval/random.json" in text
    # the paper's Pred (Table 2: 26.47 per car and episode) is named as the friendlier in-training statistic
    assert "26.47" in text and "moving average" in text


def test_a_driving_evaluation_of_another_policy_or_of_other_episodes_is_refused(tool, driving_folder, tmp_path):
    copy = tmp_path / tool.DRIVING_FOLDER
    shutil.copytree(driving_folder, copy)
    path = copy / tool.EVAL_DIR / "policy.json"
    original = path.read_text()
    result = json.loads(original)
    result["evaluated"]["sha256"] = "1" * 64
    path.write_text(json.dumps(result))
    with pytest.raises(tool.ReadmeError, match=r"policy.json evaluates another policy: its sha256 is 1{64}"):
        tool.render(tmp_path, tool.DRIVING_FOLDER)
    path.write_text(original)
    reference = copy / tool.EVAL_DIR / "random.json"
    result = json.loads(reference.read_text())
    result["settings"]["seeds"] = [0, 1, 2, 3, 4]
    reference.write_text(json.dumps(result))
    with pytest.raises(tool.ReadmeError, match=r"random.json drove other episodes than policy.json: its seeds differ"):
        tool.render(tmp_path, tool.DRIVING_FOLDER)


def _ledger_row(digest, opponent="perceiving", players=2, spec="p", **result):
    head = {"games": 100, "wins": 30, "draws": 50, "losses": 20, "goals_for": 41, "goals_against": 28,
            "goal_difference_per_game": 0.13, "interval": [0.01, 0.25], "beats": True, **result}
    return {"format": "dynenv_test_ledger/1", "date": "2026-11-29T10:00:00+00:00", "commit": "abcdef0123",
            "evaluated": {"spec": spec, "sha256": digest}, "opponent": {"spec": opponent}, "games": head["games"],
            "settings": {"players_per_team": players}, "head_to_head": head}


def _write_ledger(tool, root, rows):
    path = root / tool.LEDGER
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(json.dumps(r) for r in rows) + "\n")


def test_the_readme_lists_every_test_ledger_row_of_its_policy_and_no_other(tool, folder, tmp_path):
    digest = sha256(folder / tool.POLICY)
    lines = tool.ledger_lines(folder.parent.parent, digest)       # the repository's ledger: whatever it holds
    row = _ledger_row(digest)
    _write_ledger(tool, tmp_path, [row, dict(row, evaluated={"spec": "q", "sha256": "f" * 64}, commit="9999999"),
                                   dict(row, opponent={"spec": "scripted"})])
    text = "\n".join(tool.ledger_lines(tmp_path, digest))
    assert ("| 2026-11-29 | `abcdef0` | this file | `perceiving` | 2 | 100 | 30/50/20 | 41 : 28 | +0.130 (+0.01 to "
            "+0.25) | yes |") in text
    assert "`scripted`" in text and "9999999" not in text
    assert lines[0] == "## The test ledger"


def test_rows_of_the_same_weights_under_other_digests_are_listed_and_labelled(tool, folder, tmp_path):
    """A policy file written from a training checkpoint is the checkpoint's policy: the checkpoint's rows (its
    model.safetensors' sha256, named in the header's source_checkpoint) are listed, and so are the rows of a
    committed policy file with the same tensor data, found by the path the row names (from another checkout);
    a committed file with other weights is not."""
    here = tmp_path / "policy_node" / "pretrained"
    here.mkdir(parents=True)
    shutil.copy(folder / tool.POLICY, here / tool.POLICY)
    twin, other = tmp_path / "docs" / "twin.safetensors", tmp_path / "docs" / "other.safetensors"
    twin.parent.mkdir()
    from dynenv_ros.agent.checkpoint import load_policy, save_policy
    model, meta = load_policy(folder / tool.POLICY)
    save_policy(model, twin, {"written": "again, under other metadata"})
    import torch
    with torch.no_grad():
        next(model.parameters()).add_(1.0)
    save_policy(model, other)
    source = {"path": "/runs/x/checkpoints/step_000000000016", "step": 16, "model_sha256": "c" * 64}
    rows = [_ledger_row(sha256(here / tool.POLICY)), _ledger_row("c" * 64, opponent="scripted"),
            _ledger_row(sha256(twin), players=5, spec="/elsewhere/checkout/docs/twin.safetensors"),
            _ledger_row(sha256(other), spec="/elsewhere/checkout/docs/other.safetensors"),
            _ledger_row("d" * 64, spec="/elsewhere/checkout/docs/twin.safetensors")]     # a twin's path, not its file
    _write_ledger(tool, tmp_path, rows)
    same = tool.same_policy(tmp_path, here, {**meta, "source_checkpoint": source})
    assert [s.digest for s in same] == ["c" * 64, sha256(twin)]
    text = "\n".join(tool.ledger_lines(tmp_path, sha256(here / tool.POLICY), same_policy=same))
    assert "| this file | `perceiving` | 2 |" in text
    assert "| the training checkpoint it was written from | `scripted` | 2 |" in text
    assert "| `twin.safetensors` | `perceiving` | 5 |" in text
    assert "evaluated as the training checkpoint this file was written from (`/runs/x/checkpoints/" in text
    assert "evaluated as `docs/twin.safetensors`, a committed policy file with the same weights" in text
    assert text.count("| 2026-11-29 |") == 3


def test_the_bars_are_met_only_where_every_row_of_them_clears_them(tool, tmp_path):
    """Issue 39's bars: against perceiving at 2v2 the interval above 0 and twice as many wins as losses; against
    the ground-truth team at 2v2 and at 5v5 against perceiving the interval above 0; at least 100 games."""
    rows = [_ledger_row("a" * 64, wins=34, losses=17, interval=[0.04, 0.38], goal_difference_per_game=0.21),
            _ledger_row("a" * 64, opponent="scripted", interval=[-0.09, 0.28], goal_difference_per_game=0.09),
            _ledger_row("a" * 64, players=5, games=60, interval=[0.2, 0.5]),           # too few games: no bar
            _ledger_row("b" * 64, players=5, interval=[0.1, 0.3])]                    # another policy's row
    _write_ledger(tool, tmp_path, rows)
    text = "\n".join(tool.bar_lines(tmp_path, "a" * 64))
    assert "- **met** — against `perceiving` at 2v2: 34 wins" in text and "at least twice as many wins" in text
    assert "- **not met** — against the ground-truth `scripted` team at 2v2: 30 wins" in text
    assert "level: the interval includes 0" in text
    assert "- **not tried** — at 5v5 against `perceiving`: no test-split row." in text
    # above 0 but 30 wins to 16 losses: short of twice as many
    _write_ledger(tool, tmp_path, [_ledger_row("a" * 64, wins=30, losses=16)])
    text = "\n".join(tool.bar_lines(tmp_path, "a" * 64))
    assert "- **not met** — against `perceiving` at 2v2:" in text and "fewer than twice as many wins" in text
    # a second row of a bar that misses it: the bar is not met (every row counts, not the best one)
    _write_ledger(tool, tmp_path, [_ledger_row("a" * 64, wins=34, losses=17),
                                   _ledger_row("a" * 64, wins=34, losses=17, interval=[-0.01, 0.3])])
    assert "- **not met** — against `perceiving` at 2v2:" in "\n".join(tool.bar_lines(tmp_path, "a" * 64))


def test_the_split_of_the_evaluations_heads_their_table_and_gives_their_command(tool):
    def result(seeds):
        return {"settings": {"seeds": seeds, "episodes": 4, "players_per_team": 2, "perception": "realistic",
                             "sides": "alternate", "greedy": True, "env_config": {}},
                "evaluated": {"path": "p.safetensors"}, "opponent": {"spec": "perceiving"}}
    validation = result(list(range(10_000, 10_025)))
    assert tool.evaluation_split([(None, validation)]).startswith("validation split, seeds 10,000–10,024:")
    assert tool.evaluation_split([(None, result([100, 101, 102, 103, 104]))]).startswith(
        "seeds 100–104: train split")
    assert tool.evaluation_split([(None, result([20_000, 20_001, 20_002]))]).startswith("test split")
    assert tool.evaluation_split([(None, validation), (None, result([100]))]).endswith("of more than one split")
    assert "--split validation --num-seeds 25 " in tool.eval_command("out.json", validation)
    # not the split's first seeds: named one by one, as dynenv-eval must be given them
    assert "--seeds 10001 10002 10003 " in tool.eval_command("out.json", result([10_001, 10_002, 10_003]))
    assert tool.eval_command("out.json", validation, "here/policy.safetensors").startswith(
        ".venv/bin/dynenv-eval here/policy.safetensors --opponent perceiving")
