"""A run records what it cost as it ran (wall and CPU seconds of every process it started, the load average, the
machine), segment by segment across --resume; and ``init_policy`` starts a run from a policy file's weights."""
from __future__ import annotations

import json
import multiprocessing
import os
import time

import pytest
import torch

from dynenv_ros.agent.checkpoint import save_policy, sha256
from dynenv_ros.learning.run.compute import ComputeMeter, cpu_seconds_of_tree, machine
from dynenv_ros.learning.config import ConfigError, TrainConfig
from dynenv_ros.learning.trainer import Trainer

SMALL = {"algorithm": "ppo", "variant": "baseline", "players_per_team": 1, "num_envs": 2, "perception": "none",
         "rollout_length": 4, "ltp_horizon": 2, "feature_size": 16, "ppo_epochs": 1, "ppo_minibatches": 1,
         "log_every_updates": 1, "checkpoint_every_minutes": 10.0, "backend": "inprocess"}


def _spin(seconds: float) -> None:
    end = time.process_time() + seconds
    while time.process_time() < end:
        pass


def test_cpu_seconds_count_a_live_child_process():
    before = cpu_seconds_of_tree()
    child = multiprocessing.get_context("spawn").Process(target=_spin, args=(1.0,))
    child.start()
    # the child burns 1 s of CPU; read the tree while it is still alive, then again once it has been reaped
    deadline = time.monotonic() + 30
    while cpu_seconds_of_tree() - before < 0.6 and time.monotonic() < deadline:
        time.sleep(0.05)
    assert cpu_seconds_of_tree() - before >= 0.6
    child.join()
    assert cpu_seconds_of_tree() - before >= 0.95


def test_the_machine_names_its_cores():
    assert machine()["cores"] == os.cpu_count()


def test_segments_add_up_and_one_segment_is_an_uninterrupted_run():
    meter = ComputeMeter(0)
    meter.sample_load()
    _spin(0.2)
    first = meter.record(100)
    assert first["uninterrupted"] and len(first["segments"]) == 1
    assert first["segments"][0]["cpu_seconds"] >= 0.19 - 1e-9        # summed in floats: 0.18999999999999773 seen
    assert first["wall_seconds"] >= 0.19 - 1e-9
    resumed = ComputeMeter(100, first["segments"])
    second = resumed.record(250)
    assert not second["uninterrupted"] and second["env_steps"] == 250
    assert [s["env_steps_from"] for s in second["segments"]] == [0, 100]
    assert second["cpu_seconds"] == pytest.approx(sum(s["cpu_seconds"] for s in second["segments"]))


def test_a_run_records_its_compute_and_a_resumed_run_keeps_both_segments(tmp_path):
    cfg = TrainConfig(**{**SMALL, "total_env_steps": 16})
    summary = Trainer(cfg, tmp_path, progress=False).run()
    compute = summary["compute"]
    assert compute["uninterrupted"] and compute["env_steps"] == 16
    assert compute["cpu_seconds"] > 0 and compute["wall_seconds"] > 0
    segment = compute["segments"][0]
    assert segment["machine"]["cores"] == os.cpu_count() and segment["load_samples"] >= 1
    assert json.loads((tmp_path / "summary.json").read_text())["compute"]["env_steps"] == 16

    more = TrainConfig(**{**SMALL, "total_env_steps": 32})
    resumed = Trainer(more, tmp_path, resume=True, progress=False).run()["compute"]
    assert not resumed["uninterrupted"]
    assert [s["env_steps_from"] for s in resumed["segments"]] == [0, 16]
    assert [s["env_steps_to"] for s in resumed["segments"]] == [16, 32]


def test_init_policy_starts_every_network_from_the_file(tmp_path):
    cfg = TrainConfig(**{**SMALL, "seed": 1})
    source = Trainer(cfg, tmp_path / "a", progress=False)
    with torch.no_grad():
        for p in source.networks.agent.parameters():
            p.add_(0.5)                             # weights no fresh seed-0 run starts with
    path = tmp_path / "start.safetensors"
    save_policy(source.networks.agent, str(path))
    source.close()

    started = Trainer(TrainConfig(**{**SMALL, "init_policy": str(path)}), tmp_path / "b", progress=False)
    fresh = Trainer(TrainConfig(**SMALL), tmp_path / "c", progress=False)
    want = source.networks.agent.state_dict()
    for key, value in started.networks.agent.state_dict().items():
        assert torch.equal(value, want[key]), key
    assert any(not torch.equal(v, want[k]) for k, v in fresh.networks.agent.state_dict().items())
    started.cfg = TrainConfig(**{**SMALL, "init_policy": str(path), "total_env_steps": 8})
    summary = started.run()
    assert summary["init_policy_sha256"] == sha256(path)
    fresh.close()


def test_an_init_policy_that_does_not_fit_is_refused_naming_the_key(tmp_path):
    other = Trainer(TrainConfig(**{**SMALL, "feature_size": 8}), tmp_path / "a", progress=False)
    path = tmp_path / "narrow.safetensors"
    save_policy(other.networks.agent, str(path))
    other.close()
    with pytest.raises(ValueError, match="does not fit the model: key"):
        Trainer(TrainConfig(**{**SMALL, "init_policy": str(path)}), tmp_path / "b", progress=False)


def test_init_policy_with_a_pretrained_encoder_is_refused():
    with pytest.raises(ConfigError, match="init_policy"):
        TrainConfig(**{**SMALL, "init_policy": "a.safetensors", "pretrained_encoder": "b.safetensors"})
