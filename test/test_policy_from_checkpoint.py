"""tools/policy_from_checkpoint.py writes, from a kept training checkpoint, the files a run writes at its end: the
policy file with the trainer's own end-of-run meta (plus the checkpoint it came from), the ONNX export, the training
config and the run's counters. Checked against a real run's end: the same weights, the same meta."""
from __future__ import annotations

import json

import pytest
from tool_scripts import load_tool

from dynenv_ros.agent.checkpoint import safetensors_header, sha256
from dynenv_ros.learning.config import TrainConfig
from dynenv_ros.learning.run.checkpoints import MODEL_FILE, resolve_checkpoint
from dynenv_ros.learning.trainer import Trainer

SMALL = {"algorithm": "ppo", "variant": "baseline", "players_per_team": 1, "num_envs": 2, "perception": "none",
         "rollout_length": 4, "ltp_horizon": 2, "feature_size": 16, "ppo_epochs": 1, "ppo_minibatches": 1,
         "log_every_updates": 1, "checkpoint_every_minutes": 10.0, "backend": "inprocess", "total_env_steps": 16}
# what differs between two writes of the same run's state: the clock (the trainer reads it again for the policy file)
CLOCK = ("wall_seconds", "compute")


@pytest.fixture(scope="module")
def tool():
    return load_tool("policy_from_checkpoint")


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    """A finished tiny run: its end-of-run files and its last checkpoint (written at the end, same state)."""
    folder = tmp_path_factory.mktemp("run")
    summary = Trainer(TrainConfig(**SMALL), folder, progress=False).run()
    return folder, summary


def _header(path):
    metadata = safetensors_header(path.read_bytes())[0]["__metadata__"]
    return metadata, json.loads(metadata["meta"])


def test_the_files_are_the_runs_end_of_run_files_with_their_checkpoint_named(tool, run, tmp_path):
    folder, summary = run
    out = tmp_path / "shipped"
    out.mkdir()
    assert tool.main([str(folder), str(out)]) == 0
    (written, meta), (ended, end_meta) = _header(out / "policy.safetensors"), _header(folder / "policy.safetensors")
    assert written["data_sha256"] == ended["data_sha256"]              # the same weights, byte for byte
    assert written["config"] == ended["config"]
    source = meta.pop("source_checkpoint")
    assert {k: v for k, v in meta.items() if k not in CLOCK} == {k: v for k, v in end_meta.items() if k not in CLOCK}
    checkpoint = resolve_checkpoint(folder)
    assert source["path"] == str(checkpoint) and source["step"] == SMALL["total_env_steps"]
    assert source["model_sha256"] == sha256(checkpoint / MODEL_FILE)
    assert json.loads((out / "train_config.json").read_text()) == json.loads((folder / "config.json").read_text())
    counters = json.loads((out / "train_summary.json").read_text())
    assert {k: counters[k] for k in ("env_steps", "updates", "episodes")} == \
        {k: summary[k] for k in ("env_steps", "updates", "episodes")}
    assert "init_policy_sha256" not in counters                          # the run started from scratch
    assert (out / "policy.onnx").stat().st_size > 0


def test_a_run_from_a_policy_file_records_that_files_sha256_and_a_missing_one_is_refused(tool, run, tmp_path):
    folder, _ = run
    meta = {"env_steps": 16, "config": {"init_policy": str(folder / "policy.safetensors")}}
    assert tool.training_summary(meta)["init_policy_sha256"] == sha256(folder / "policy.safetensors")
    with pytest.raises(ValueError, match="started from nowhere.safetensors, which is not here"):
        tool.training_summary({"config": {"init_policy": "nowhere.safetensors"}}, root=tmp_path)


def test_a_folder_that_does_not_exist_or_a_missing_checkpoint_is_one_line(tool, run, tmp_path, capsys):
    folder, _ = run
    assert tool.main([str(folder), str(tmp_path / "absent")]) == 2
    assert f"folder {tmp_path / 'absent'} does not exist" in capsys.readouterr().err
    assert tool.main([str(tmp_path / "no_run"), str(tmp_path)]) == 2
    assert f"checkpoint {tmp_path / 'no_run'} does not exist" in capsys.readouterr().err


def test_a_kept_policy_file_is_copied_as_it_is_beside_the_files_it_implies(tool, run, tmp_path, capsys):
    """A run's kept copy (a policy file the trainer wrote) ships byte for byte, so the SHA-256 its evaluations recorded
    stays its own; the config and counters come from its header. A policy file without a training config (one saved
    by hand) is refused in one line."""
    folder, summary = run
    out = tmp_path / "shipped"
    out.mkdir()
    assert tool.main([str(folder / "policy.safetensors"), str(out)]) == 0
    assert sha256(out / "policy.safetensors") == sha256(folder / "policy.safetensors")
    assert json.loads((out / "train_config.json").read_text()) == json.loads((folder / "config.json").read_text())
    counters = json.loads((out / "train_summary.json").read_text())
    assert {k: counters[k] for k in ("env_steps", "updates", "episodes")} == \
        {k: summary[k] for k in ("env_steps", "updates", "episodes")}
    assert (out / "policy.onnx").stat().st_size > 0
    from dynenv_ros.agent.checkpoint import load_policy, save_policy
    bare = tmp_path / "bare.safetensors"
    save_policy(load_policy(folder / "policy.safetensors")[0], bare)
    assert tool.main([str(bare), str(out)]) == 2
    assert "carries no training config in its header" in capsys.readouterr().err
