"""policy_node/pretrained/README.md is what tools/pretrained_readme.py makes of the files beside it (so it cannot
drift from the policy), names the policy file's sha256, and the generator refuses the evaluation of another policy."""
from __future__ import annotations

import json
import shutil

import pytest
from tool_scripts import load_tool

from dynenv_ros.agent.checkpoint import sha256


@pytest.fixture(scope="module")
def tool():
    return load_tool("pretrained_readme")


@pytest.fixture(scope="module")
def folder(tool):
    return tool.ROOT / tool.FOLDER


def test_the_committed_readme_is_what_the_files_give(tool, folder):
    try:
        expected = tool.render()
    except tool.GitUnknown as error:         # a clone without the history the README's fix check reads
        pytest.skip(str(error))
    assert (folder / "README.md").read_text() == expected, "run .venv/bin/python tools/pretrained_readme.py"


def test_the_readme_names_the_policy_files_sha256_and_its_evaluations_are_of_that_file(tool, folder):
    digest, text = sha256(folder / tool.POLICY), (folder / "README.md").read_text()
    assert f"sha256 `{digest}`" in text
    evaluations = sorted((folder / tool.EVAL_DIR).glob("*.json"))
    assert {path.stem for path in evaluations} >= {"vs_random", "vs_scripted", "vs_perceiving"}
    for path in evaluations:
        assert json.loads(path.read_text())["evaluated"]["sha256"] == digest, path
        assert f"--out policy_node/pretrained/eval/{path.name}" in text


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


def test_the_readme_lists_every_test_ledger_row_of_its_policy_and_no_other(tool, folder):
    digest = sha256(folder / tool.POLICY)
    row = {"format": "dynenv_test_ledger/1", "date": "2026-11-29T10:00:00+00:00", "commit": "abcdef0123",
           "evaluated": {"spec": "p", "sha256": digest}, "opponent": {"spec": "perceiving"}, "games": 100,
           "head_to_head": {"games": 100, "wins": 30, "draws": 50, "losses": 20, "goals_for": 41, "goals_against": 28,
                            "goal_difference_per_game": 0.13, "interval": [0.01, 0.25], "beats": True}}
    other = dict(row, evaluated={"spec": "q", "sha256": "f" * 64}, commit="9999999")
    lines = tool.ledger_lines(folder.parent.parent, digest)       # the repository's ledger: whatever it holds
    ledger = [json.dumps(r) for r in (row, other, dict(row, opponent={"spec": "scripted"}))]
    import tempfile
    from pathlib import Path
    with tempfile.TemporaryDirectory() as root:
        path = Path(root) / tool.LEDGER
        path.parent.mkdir(parents=True)
        path.write_text("\n".join(ledger) + "\n")
        text = "\n".join(tool.ledger_lines(Path(root), digest))
    assert "| 2026-11-29 | `abcdef0` | `perceiving` | 100 | 30/50/20 | 41 : 28 | +0.130 (+0.01 to +0.25) | yes |" in text
    assert "`scripted`" in text and "9999999" not in text
    assert lines[0] == "## The test ledger"
