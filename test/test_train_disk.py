"""dynenv-train and dynenv-eval against a bad disk and an early kill (issue 27 item 4): a read-only run directory or
output file is refused in one line before any work and leaves nothing behind; a disk that fills mid-run stops the
run cleanly with the last checkpoint loadable; the first checkpoint comes within seconds, so a SIGKILL right after
the start still leaves a run that --resume continues.

Read-only: a folder with mode 0o555. Where that is not enforced (running as root), the same test uses a folder of
sysfs, /sys/fs, which even root cannot create files in; a second case is a path under a regular file."""
import errno
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from dynenv_ros.evaluation.cli import main as eval_main
from dynenv_ros.learning.run import checkpoints
from dynenv_ros.learning.train_cli import main

ROOT = Path(__file__).resolve().parent.parent
TINY = ["--set", "num_envs=1", "--set", "players_per_team=1", "--set", "backend=inprocess",
        "--set", "rollout_length=4", "--set", "ltp_horizon=4"]


def _one_line(err: str) -> str:
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1 and "Traceback" not in err, err
    return lines[0]


@pytest.fixture(params=["mode_0o555", "under_a_file"])
def read_only(request, tmp_path):
    """(a folder nothing can be created in, a check that nothing was left)."""
    if request.param == "under_a_file":
        blocker = tmp_path / "a_file"
        blocker.write_text("x")
        yield blocker / "sub", lambda: sorted(os.listdir(tmp_path)) == ["a_file"] and blocker.read_text() == "x"
        return
    folder = tmp_path / "ro"
    folder.mkdir()
    folder.chmod(0o555)
    try:
        probe = folder / "probe"
        try:
            probe.write_text("x")
            probe.unlink()
            enforced = False            # root: mode bits are not enforced
        except PermissionError:
            enforced = True
        if enforced:
            yield folder, lambda: os.listdir(folder) == []
        else:
            sysfs = Path("/sys/fs")
            before = sorted(os.listdir(sysfs))
            yield sysfs, lambda: sorted(os.listdir(sysfs)) == before
    finally:
        folder.chmod(0o755)


def test_read_only_run_dir_is_refused_in_one_line_before_training_and_leaves_nothing(read_only, capsys):
    folder, nothing_left = read_only
    run_dir = folder / "run"
    assert main(["--config", "quick", "--run-dir", str(run_dir), "--no-progress", *TINY]) == 2
    line = _one_line(capsys.readouterr().err)
    assert line.startswith("dynenv-train: --run-dir ") and "not writable" in line, line
    assert nothing_left()


def test_resume_into_a_full_run_dir_is_refused_in_one_line(tmp_path, capsys, monkeypatch):
    run_dir = tmp_path / "run"
    assert main(["--config", "quick", "--run-dir", str(run_dir), "--no-progress", *TINY,
                 "--set", "total_env_steps=4"]) == 0
    capsys.readouterr()
    from dynenv_ros.core import writable

    def full(path, mode="r", *args, **kwargs):      # the probe's file is created, its write finds the disk full
        handle = open(path, mode, *args, **kwargs)
        handle.write = lambda data: (_ for _ in ()).throw(OSError(errno.ENOSPC, "No space left on device"))
        return handle
    monkeypatch.setattr(writable, "open", full, raising=False)
    assert main(["--resume", str(run_dir), "--no-progress", "--set", "total_env_steps=8"]) == 2
    line = _one_line(capsys.readouterr().err)
    assert line == f"dynenv-train: --resume {run_dir} is not writable: no space left on device", line
    assert not [p for p in run_dir.iterdir() if p.name.startswith(".dynenv-probe")]


def test_disk_full_mid_run_stops_cleanly_and_keeps_the_last_checkpoint(tmp_path, capsys, monkeypatch):
    """The writer raises ENOSPC in-process from the second checkpoint on: the run stops with one line, exit 1, and
    the first checkpoint is still complete and loadable (no temp folder left)."""
    from dynenv_ros.learning.config import TrainConfig
    from dynenv_ros.learning.trainer import Trainer
    real = checkpoints.write_synced
    checkpoints_started = []

    def write_synced(path, data):
        if path.name == "model.safetensors":
            checkpoints_started.append(path)
        if len(checkpoints_started) >= 2:
            raise OSError(errno.ENOSPC, "No space left on device", str(path))
        return real(path, data)
    monkeypatch.setattr(checkpoints, "write_synced", write_synced)
    run_dir = tmp_path / "run"
    code = main(["--config", "quick", "--run-dir", str(run_dir), "--no-progress", *TINY,
                 "--set", "checkpoint_every_minutes=0.0001", "--set", "total_env_steps=400"])
    assert code == 1
    line = _one_line(capsys.readouterr().err)
    assert line.startswith(f"dynenv-train: stopped early: cannot write to {run_dir}: no space left on device"), line
    assert len(checkpoints_started) == 2
    assert [p.name for p in (run_dir / "checkpoints").iterdir() if p.name.startswith(".")] == []
    monkeypatch.setattr(checkpoints, "write_synced", real)
    meta = checkpoints.read_checkpoint_meta(run_dir)          # verifies every file's SHA-256
    assert meta["env_steps"] == 0
    trainer = Trainer(TrainConfig.from_dict(json.loads((run_dir / "config.json").read_text())), run_dir,
                      resume=True, progress=False)
    try:
        assert trainer.progress.env_steps == 0
    finally:
        trainer.close()


def test_sigkill_right_after_the_first_checkpoint_then_resume_continues(tmp_path, capsys):
    """The first checkpoint comes as the run starts (not after checkpoint_every_minutes, here 5): poll for it for at
    most 40 s, SIGKILL the real dynenv-train, and --resume continues from it."""
    run_dir = tmp_path / "run"
    command = [sys.executable, "-m", "dynenv_ros.learning.train_cli", "--config", "quick", "--run-dir",
               str(run_dir), "--no-progress", *TINY, "--set", "checkpoint_every_minutes=5",
               "--set", "total_env_steps=100000", "--set", "max_minutes=5"]
    started = time.monotonic()
    process = subprocess.Popen(command, cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    try:
        while not checkpoints.list_checkpoints(run_dir):
            assert process.poll() is None, process.stderr.read().decode()
            assert time.monotonic() - started < 40, "no checkpoint within 40 s of the start"
            time.sleep(0.1)
        os.kill(process.pid, signal.SIGKILL)
        process.wait(timeout=30)
    finally:
        if process.poll() is None:
            process.kill()
            process.wait()
        process.stderr.close()
    assert process.returncode == -signal.SIGKILL
    first = checkpoints.read_checkpoint_meta(run_dir)
    assert main(["--resume", str(run_dir), "--no-progress", "--set", "total_env_steps=8"]) == 0
    err = capsys.readouterr().err
    assert "no checkpoint" not in err and "Traceback" not in err, err
    summary = json.loads((run_dir / "summary.json").read_text())
    assert summary["env_steps"] == 8 and summary["updates"] == (8 - first["env_steps"]) // 4 + first["updates"]


def test_resume_of_a_run_killed_before_its_first_checkpoint_starts_it_again(tmp_path, capsys):
    run_dir = tmp_path / "run"
    assert main(["--config", "quick", "--run-dir", str(run_dir), "--no-progress", *TINY,
                 "--set", "total_env_steps=4"]) == 0
    import shutil
    shutil.rmtree(run_dir / "checkpoints")         # what a kill in the first second leaves: config.json only
    (run_dir / "summary.json").unlink()
    capsys.readouterr()
    assert main(["--resume", str(run_dir), "--no-progress", "--set", "total_env_steps=8"]) == 0
    assert "starting it again from the beginning" in capsys.readouterr().err
    assert json.loads((run_dir / "summary.json").read_text())["env_steps"] == 8


def test_eval_out_read_only_is_refused_in_one_line_exit_2_before_evaluating(read_only, capsys, monkeypatch,
                                                                          tmp_path_factory):
    folder, nothing_left = read_only
    import dynenv_ros.evaluation.soccer as soccer
    monkeypatch.setattr(soccer, "evaluate", lambda *a, **k: pytest.fail("evaluated before checking --out"))
    out = folder / "eval.json"
    assert eval_main(["random", "--episodes", "1", "--seeds", "0", "--quiet", "--out", str(out)]) == 2
    line = _one_line(capsys.readouterr().err)
    assert line.startswith(f"dynenv-eval: --out {out}"), line
    a = tmp_path_factory.mktemp("inputs") / "a.json"
    a.write_text("{}")
    assert eval_main(["merge", str(a), "--out", str(out)]) == 2
    assert _one_line(capsys.readouterr().err).startswith(f"dynenv-eval: --out {out}")
    assert eval_main(["compare", str(a), str(a), "--out", str(out)]) == 2
    assert _one_line(capsys.readouterr().err).startswith(f"dynenv-eval: --out {out}")
    assert nothing_left()


def test_a_disk_too_small_for_the_runs_checkpoints_is_refused_in_one_line_and_nothing_is_made(tmp_path, capsys,
                                                                                              monkeypatch):
    """A disk with room for the probe but not for the run (keep_checkpoints + 1 checkpoints, the policy files, the
    logs) is refused up front, exit 2, naming what is needed and what is free; no folder is made. Free space is
    faked at 5 MB, the size that used to leave a run folder with no checkpoint."""
    import shutil
    from collections import namedtuple
    from dynenv_ros.core import writable
    usage = namedtuple("usage", "total used free")
    monkeypatch.setattr(writable.shutil, "disk_usage", lambda path: usage(10 * 2**20, 5 * 2**20, 5 * 2**20))
    run_dir = tmp_path / "runs" / "small_disk"
    code = main(["--config", "quick", "--run-dir", str(run_dir), "--no-progress", *TINY])
    assert code == 2
    line = _one_line(capsys.readouterr().err)
    assert line.startswith(f"dynenv-train: --run-dir {run_dir}: needs about ") and "5.0 MB free" in line, line
    assert "checkpoints of" in line
    assert not (tmp_path / "runs").exists()
    assert shutil.disk_usage is not None


def test_the_disk_estimate_covers_what_a_run_writes(tmp_path):
    """The estimate of one checkpoint is within 10 % of a real checkpoint folder's size for a variant that trains
    every head (pred: Adam then holds moments of every parameter; a baseline run's unused heads have none, so its
    estimate errs on the safe side), and the estimate of the whole run is at least what a finished run left."""
    from dynenv_ros.learning.config import load_config
    from dynenv_ros.learning.run.disk_budget import LOG_BYTES, run_disk_bytes
    from dynenv_ros.learning.train_cli import preset_path
    run_dir = tmp_path / "run"
    pred = [*TINY, "--set", "variant=pred"]
    assert main(["--config", "quick", "--run-dir", str(run_dir), "--no-progress", *pred,
                 "--set", "total_env_steps=16"]) == 0
    cfg = load_config(preset_path("quick"), [item for item in pred if item != "--set"])
    needed, _ = run_disk_bytes(cfg)
    folder = max(checkpoints.list_checkpoints(run_dir), key=lambda path: path.name)   # after updates: Adam's state
    checkpoint = sum(f.stat().st_size for f in folder.iterdir())
    per_checkpoint = (needed - LOG_BYTES - 2 * (run_dir / "policy.safetensors").stat().st_size) \
        / (cfg.keep_checkpoints + 1)
    assert abs(per_checkpoint - checkpoint) < 0.10 * checkpoint, (per_checkpoint, checkpoint)
    written = sum(f.stat().st_size for f in run_dir.rglob("*") if f.is_file())
    assert written <= needed
