"""dynenv-train end to end: bad configs refused before any work, a real SIGKILL mid-run, and resumption from the
last checkpoint with the networks, optimiser state and step counters as they were saved."""
import hashlib
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import torch

from dynenv_ros.learning.run import checkpoints
from dynenv_ros.learning.config import TrainConfig
from dynenv_ros.learning.train_cli import main
from dynenv_ros.learning.trainer import Trainer

ROOT = Path(__file__).resolve().parent.parent
TINY = ["--set", "num_envs=1", "--set", "players_per_team=1", "--set", "backend=inprocess",
        "--set", "rollout_length=4", "--set", "ltp_horizon=4"]


@pytest.mark.parametrize("override, key", [("nope=1", "nope"), ("num_envs=two", "num_envs"),
                                           ("gamma=1.5", "gamma"), ("num_envs=true", "num_envs"),
                                           ("algorithm=sac", "algorithm")])
def test_bad_config_is_refused_naming_the_key(tmp_path, capsys, override, key):
    code = main(["--config", "quick", "--run-dir", str(tmp_path / "run"), "--set", override])
    assert code == 2
    err = capsys.readouterr().err
    assert key in err and "Traceback" not in err
    assert not (tmp_path / "run").exists()          # refused before any work


def test_help_lists_every_config_key_with_its_default(capsys):
    import dataclasses
    with pytest.raises(SystemExit) as exit_info:
        main(["--help"])
    assert exit_info.value.code == 0
    text = capsys.readouterr().out
    for field in dataclasses.fields(TrainConfig):
        assert f"  {field.name} (default " in text, field.name
    assert "teacher (default None)" in text and "learning_rate (default 0.0001)" in text


def test_unknown_preset_and_cuda_without_gpu_are_refused(tmp_path, capsys):
    assert main(["--config", "no_such_preset", "--run-dir", str(tmp_path / "a")]) == 2
    assert "no config preset" in capsys.readouterr().err
    if not torch.cuda.is_available():
        assert main(["--config", "quick", "--device", "cuda", "--run-dir", str(tmp_path / "b")]) == 2
        assert "CUDA" in capsys.readouterr().err


def _latest_step(run_dir) -> int:
    try:
        return int(checkpoints.read_checkpoint_meta(run_dir)["env_steps"])
    except (ValueError, OSError, KeyError):       # not written yet
        return 0


def test_sigkill_then_resume_from_the_last_checkpoint(tmp_path):
    run_dir = tmp_path / "run"
    command = [sys.executable, "-m", "dynenv_ros.learning.train_cli", "--config", "quick", "--run-dir",
               str(run_dir), "--no-progress", *TINY, "--set", "checkpoint_every_minutes=0.001",
               "--set", "total_env_steps=100000", "--set", "max_minutes=5"]
    process = subprocess.Popen(command, cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    try:
        deadline = time.monotonic() + 480
        while time.monotonic() < deadline:
            found = checkpoints.list_checkpoints(run_dir / "checkpoints") if (run_dir / "checkpoints").exists() \
                else []
            # a checkpoint folder appears before `latest` names it (rename, then the pointer's atomic write): kill
            # only once the pointer has moved past the first checkpoint (step 0), or a loaded machine can land the
            # kill between the two and the run resumes, correctly, from step 0
            if len(found) >= 2 and _latest_step(run_dir) > 0:
                break
            assert process.poll() is None, process.stderr.read().decode()
            time.sleep(0.2)
        else:
            pytest.fail("no checkpoint within 480 s")
        os.kill(process.pid, signal.SIGKILL)
        process.wait(timeout=30)
    finally:
        if process.poll() is None:
            process.kill()
    assert process.returncode == -signal.SIGKILL

    meta = checkpoints.read_checkpoint_meta(run_dir)
    saved_steps = meta["env_steps"]
    cfg = TrainConfig.from_dict(json.loads((run_dir / "config.json").read_text()))
    trainer = Trainer(cfg, run_dir, resume=True, progress=False)
    try:
        latest = checkpoints.resolve_checkpoint(run_dir)
        model_state, _ = checkpoints.read_safetensors((latest / "model.safetensors").read_bytes())
        for name, value in trainer.networks.state_dict().items():
            assert torch.equal(value, model_state[name]), name
        assert trainer.progress.env_steps == saved_steps and trainer.progress.env_steps % 4 == 0 and trainer.progress.env_steps > 0
        assert trainer.progress.updates == trainer.progress.env_steps // 4
        # the optimizer resumes with exactly the saved state; a parameter whose loss term had no gradient in
        # some update (a class absent from that batch) has a smaller Adam step, which is why steps may differ
        saved_optimizer, _ = checkpoints.read_safetensors((latest / "optimizer.safetensors").read_bytes())
        resumed = trainer.optimizer.state_dict()["state"]
        for key, value in saved_optimizer.items():
            kind, index, field = key.split(".", 2)
            if kind == "state":
                assert torch.equal(torch.as_tensor(resumed[int(index)][field]), value), key
        adam_steps = [float(s["step"]) for s in trainer.optimizer.state.values()]
        assert max(adam_steps) == float(trainer.progress.updates) and min(adam_steps) >= 1.0
    finally:
        trainer.close()

    # killed before it wrote policy.safetensors, the run can still be evaluated: its latest checkpoint's policy
    from dynenv_ros.evaluation.cli import main as eval_main
    from dynenv_ros.learning.run.checkpoints import policy_from_training_checkpoint
    assert not (run_dir / "policy.safetensors").exists()
    agent, meta = policy_from_training_checkpoint(run_dir)
    assert meta["checkpoint"]["path"] == str(latest) and not agent.training
    for name, value in agent.state_dict().items():
        assert torch.equal(value, model_state["agent." + name]), name
    out = tmp_path / "eval.json"
    # a 2 s episode: what is checked is which weights were evaluated, not how they play
    assert eval_main([str(run_dir), "--opponent", "random", "--episodes", "1", "--seeds", "0", "--quiet",
                      "--players-per-team", str(cfg.players_per_team), "--episode-seconds", "2",
                      "--out", str(out)]) == 0
    digest = hashlib.sha256((latest / "model.safetensors").read_bytes()).hexdigest()
    assert json.loads(out.read_text())["evaluated"]["sha256"] == digest

    # the CLI resumes and finishes the run: two more updates
    target = saved_steps + 8
    code = main(["--resume", str(run_dir), "--no-progress", "--set", f"total_env_steps={target}"])
    assert code == 0
    summary = json.loads((run_dir / "summary.json").read_text())
    assert summary["env_steps"] == target and summary["updates"] == target // 4
    assert (run_dir / "policy.safetensors").is_file() and (run_dir / "policy.onnx").is_file()
    assert (run_dir / "curves.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    header = (run_dir / "metrics.csv").read_text().splitlines()[0]
    assert header == "env_steps,update,wall_seconds,name,value"
    agent, policy_meta = checkpoints.load_policy(run_dir / "policy.safetensors")
    assert policy_meta["env_steps"] == target and policy_meta["variant"] == cfg.variant


def test_metrics_csv_survives_a_row_cut_by_a_kill(tmp_path):
    from dynenv_ros.learning.run.metrics import RunLogger, read_metrics
    (tmp_path / "metrics.csv").write_text("env_steps,update,wall_seconds,name,value\n48,1,0.5,train/loss,1.5\n96,2,1.")
    logger = RunLogger(tmp_path, tensorboard=False)
    logger.log(96, 2, 1.0, {"train/loss": 0.5})
    logger.close()
    series = read_metrics(tmp_path / "metrics.csv")
    assert series["train/loss"] == ([48, 96], [1.5, 0.5])


def test_empty_metrics_file_gets_its_header(tmp_path):
    from dynenv_ros.learning.run.metrics import RunLogger
    (tmp_path / "metrics.csv").write_text("")          # killed before the header reached the disk
    RunLogger(tmp_path, tensorboard=False).close()
    assert (tmp_path / "metrics.csv").read_text() == "env_steps,update,wall_seconds,name,value\n"


def test_resume_of_a_folder_that_is_no_run_is_refused(tmp_path, capsys):
    assert main(["--resume", str(tmp_path)]) == 2
    assert "not a run directory" in capsys.readouterr().err


def test_resume_with_every_checkpoint_damaged_is_refused_and_loses_nothing(tmp_path, capsys):
    run_dir = tmp_path / "run"
    assert main(["--config", "quick", "--run-dir", str(run_dir), "--no-progress", *TINY,
                 "--set", "total_env_steps=4"]) == 0
    capsys.readouterr()
    damaged = {}
    for folder in (run_dir / "checkpoints").glob("step_*"):     # the first (step 0) and the last
        weights = folder / "model.safetensors"
        data = bytearray(weights.read_bytes())
        data[-1] ^= 0xFF
        weights.write_bytes(bytes(data))
        damaged[weights] = bytes(data)
    assert len(damaged) == 2
    assert main(["--resume", str(run_dir), "--no-progress", "--set", "total_env_steps=8"]) == 2
    err = capsys.readouterr().err
    assert "dynenv-train:" in err and "Traceback" not in err
    assert all(path.read_bytes() == data for path, data in damaged.items())   # the evidence is left as it was


def test_missing_pretrained_encoder_is_refused(tmp_path, capsys):
    code = main(["--config", "quick", "--run-dir", str(tmp_path / "run"), "--set", "variant=recon",
                 "--set", f"pretrained_encoder={tmp_path / 'nope.safetensors'}"])
    assert code == 2 and "does not exist" in capsys.readouterr().err
