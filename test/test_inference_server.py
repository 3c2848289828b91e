"""The inference server of the asynchronous runner (``inference: server``): it acts for every worker's robots as
the workers would act themselves, survives a worker's death, stops the run in one line when it dies, and a run that
uses it trains, checkpoints and resumes. Everything here runs on the CPU.

Equivalence, and why the tolerance. The server draws each worker's actions from a generator of the worker's own
acting seed, over that worker's rows only, so for equal logits it draws the worker's actions to the last bit. The
logits themselves come from a forward over several workers' robots at once, where float32 matrix products may sum
in another order than in a worker's smaller batch: values and log-probabilities may differ in their last bits
(1e-5 is a hundred times what that gives at these sizes). Discrete actions are compared exactly — a draw that fell
on the other side of a boundary because of such a difference would show up as a different action; continuous ones
(driving's Gaussian command: the mean plus the scale times the same normal draw) within the tolerance, as they carry
the logits' last bits. With a snapshot
opponent the server's draws are still the worker's own, but a worker acting itself shares its generator with the
opponent, which interleaves their draws; the equivalence is tested with opponents that draw nothing from it."""
from __future__ import annotations

import csv
import json
import os
import signal
import time
from pathlib import Path

import numpy as np
import pytest
import torch

from dynenv_ros.learning.algo.networks import TrainingNetworks, make_agent
from dynenv_ros.learning.config import ConfigError, TrainConfig
from dynenv_ros.learning.distributed.inference_server import BatchedActing, StepRequest
from dynenv_ros.learning.distributed.rollout_transfer import flatten
from dynenv_ros.learning.distributed.rollout_worker import resolve_workers
from dynenv_ros.learning.distributed.worker_pool import ProcessPool, WorkerPoolError
from dynenv_ros.learning.sampling.worlds import make_worlds
from dynenv_ros.learning.train_cli import main
from dynenv_ros.learning.trainer import Trainer

# 1v1, 2 worlds a worker, ground-truth perception, 1-second episodes (a truncation in every other rollout or so)
SMALL = {"algorithm": "ppo", "variant": "baseline", "players_per_team": 1, "num_envs": 4, "perception": "none",
         "rollout_length": 4, "ltp_horizon": 2, "feature_size": 16, "ppo_epochs": 1, "ppo_minibatches": 1,
         "log_every_updates": 1, "checkpoint_every_minutes": 10.0, "runner": "async", "episode_seconds": 1.0}
TOLERANCE = 1e-5


def small(**changes) -> TrainConfig:
    return TrainConfig(**{**SMALL, **changes})


# -- settings ------------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("changes", [
    {"runner": "sync", "inference": "server"},                   # no workers to serve
    {"backend": "ray", "inference": "server"},                   # Ray actors act themselves
    {"inference": "gpu"},
])
def test_inference_settings_that_cannot_work_are_refused_naming_the_key(changes):
    with pytest.raises(ConfigError) as error:
        small(**changes)
    assert error.value.key == "inference"


def test_the_server_takes_a_core_from_the_workers_only_where_it_is_one_more_process():
    """Four cores: a CPU learner and a server leave two workers; a GPU learner leaves the learner's core too."""
    assert resolve_workers(small(num_envs=8), cores=4) == 3
    assert resolve_workers(small(num_envs=8, inference="server"), cores=4) == 2
    assert resolve_workers(small(num_envs=8, inference="server", device="cuda"), cores=4) == 3


# -- the batched forward against each worker's own acting ------------------------------------------------------------
def _rollouts(cfg: TrainConfig, networks: TrainingNetworks, seed: int, count: int, driven: int) -> list:
    """``count`` rollouts of a worker acting itself (``LocalActing``) with a generator of ``seed``."""
    worlds = make_worlds(cfg, networks, 2, "inprocess", torch.Generator().manual_seed(seed),
                         np.random.default_rng(seed), seed=seed)
    try:
        worlds.collector.drive_with_teacher(driven)
        return [worlds.collector.collect(cfg.rollout_length) for _ in range(count)]
    finally:
        worlds.env.close()


@pytest.mark.parametrize("changes", [
    {"teacher": "chaser", "imitation_coef": 1.0},                                     # one worker's world driven
    {"variant": "pred", "use_localization": True, "privileged_pose_seeding": True},   # seeded starts
    {"scenario": "driving", "players_per_team": 2, "action_mode": "continuous", "n_cars": 2},
], ids=["teacher_driven", "pose_seeding", "driving_continuous"])
def test_one_forward_over_two_workers_acts_as_each_worker_acted_itself(changes):
    """Two workers' rollouts, each acted in its own process's way (``LocalActing``, its own generator), replayed
    through ``BatchedActing`` with both workers in every forward: the same actions, and values, log-probabilities
    and start states within the tolerance (module docstring), period by period, over two rollouts."""
    cfg = small(**changes)
    torch.manual_seed(3)
    networks = TrainingNetworks(make_agent(cfg), cfg.ltp_horizon).eval()
    seeds = {0: 11, 1: 12}
    teacher = cfg.teacher is not None
    made = {w: _rollouts(cfg, networks, seeds[w], 2, driven=1 if teacher and w == 0 else 0) for w in seeds}
    server = BatchedActing(networks)
    for w, seed in seeds.items():
        server.add(w, seed, made[w][0].robots, getattr(networks.agent, "layout_spec", None))
    assert made[0][0].robots == made[1][0].robots
    compared = 0
    with torch.inference_mode():
        for r in range(2):
            for w in seeds:
                if made[w][r].seed_pose is not None:
                    server.seed(w, made[w][r].seed_pose)
            T = made[0][r].steps
            for t in range(T + 1):
                requests = [StepRequest(w, {k: v[t] for k, v in made[w][r].obs.items()}, made[w][r].starts[t],
                                        last=t == T, want_state=t == 0,
                                        teacher=made[w][r].teacher_actions[t] if teacher and t < T else None,
                                        driven=made[w][r].teacher_driven if teacher else None) for w in seeds]
                for w, acted in zip(seeds, server.step(requests)):
                    rollout = made[w][r]
                    np.testing.assert_allclose(acted.values, rollout.values[t], atol=TOLERANCE)
                    if t == 0:
                        for served, own in zip(acted.start_state, rollout.initial_state):
                            np.testing.assert_allclose(served.numpy(), own.numpy(), atol=TOLERANCE)
                    if t < T:
                        if np.issubdtype(rollout.actions.dtype, np.integer):
                            np.testing.assert_array_equal(acted.actions, rollout.actions[t])
                        else:
                            np.testing.assert_allclose(acted.actions, rollout.actions[t], atol=TOLERANCE)
                        np.testing.assert_allclose(acted.log_probs, rollout.log_probs[t], atol=TOLERANCE)
                        compared += 1
    assert compared == 2 * 2 * cfg.rollout_length
    assert server.forwards == 2 * (cfg.rollout_length + 1) and server.forward_robots == 2 * server.forwards * \
        made[0][0].robots                                   # every forward carried both workers' robots
    if teacher:
        assert made[0][0].teacher_driven.any() and not made[1][0].teacher_driven.any()


# -- through the processes -----------------------------------------------------------------------------------------
def _first_rollouts(cfg: TrainConfig, networks: TrainingNetworks, count: int) -> dict[int, list[dict]]:
    pool = ProcessPool(cfg, networks, workers=2, first_update=0, log=lambda line: None)
    got: dict[int, list[dict]] = {0: [], 1: []}
    try:
        while min(len(v) for v in got.values()) < count:
            delivery = pool.get(timeout=120)
            if delivery is None:
                continue
            got[delivery.worker].append({k: np.array(v) for k, v in flatten(delivery.rollout).items()})
            assert delivery.info["version"] == 0
            pool.release(delivery, 0)
    finally:
        pool.close()
    return got


def test_worker_processes_served_by_the_server_make_the_rollouts_they_make_acting_themselves():
    """Two worker processes, 1-second episodes (truncations, so final values through the server too): their first
    two rollouts each with ``inference: server`` are those of ``inference: worker`` — the same observations,
    actions and everything else, the floats within the tolerance."""
    cfg = small(workers=2)
    torch.manual_seed(0)
    networks = TrainingNetworks(make_agent(cfg), cfg.ltp_horizon)
    own = _first_rollouts(cfg, networks, 2)
    served = _first_rollouts(cfg.replace(inference="server"), networks, 2)
    floats = ("log_probs", "values", "final_values")
    truncated = 0
    for w in (0, 1):
        for a, b in zip(own[w], served[w]):
            assert set(a) == set(b)
            for key in a:
                if key in floats or key.startswith("initial_state/"):
                    np.testing.assert_allclose(b[key], a[key], atol=TOLERANCE, err_msg=key)
                else:
                    np.testing.assert_array_equal(b[key], a[key], err_msg=key)
            truncated += int(a["truncated"].sum())
    assert truncated > 0                                     # the final values were asked of the server


def test_a_dead_worker_is_replaced_and_served_and_a_dead_server_stops_the_run_in_one_line():
    cfg = small(workers=2, worker_restarts=1, inference="server")
    networks = TrainingNetworks(make_agent(cfg), cfg.ltp_horizon)
    lines: list[str] = []
    pool = ProcessPool(cfg, networks, workers=2, first_update=0, log=lines.append)
    try:
        first = pool.get(timeout=120)
        assert first is not None and pool.server is not None
        os.kill(pool.pids()[0], signal.SIGKILL)              # worker 0
        pool.release(first, 0)
        deadline = time.monotonic() + 180
        replaced = None
        while replaced is None and time.monotonic() < deadline:
            delivery = pool.get(timeout=5)
            if delivery is not None:
                if delivery.worker == 0 and pool.deaths == 1:
                    replaced = delivery                     # the replacement's rollout, acted by the server
                else:
                    pool.release(delivery, 0)
        assert replaced is not None and pool.restarts == 1 and "died" in lines[0]
        pool.release(replaced, 0)
        os.kill(pool.server.pid, signal.SIGKILL)
        started = time.monotonic()
        with pytest.raises(WorkerPoolError) as error:
            while time.monotonic() - started < 120:
                delivery = pool.get(timeout=5)
                if delivery is not None:
                    pool.release(delivery, 0)
        message = str(error.value)
        assert message == "the inference server died (exit code -9)", message
    finally:
        pool.close()
    assert pool.server is None                               # closed with the pool


# -- a whole run ---------------------------------------------------------------------------------------------------
def test_a_run_with_the_server_trains_checkpoints_and_resumes(tmp_path):
    run_dir = tmp_path / "run"
    sets = [f"--set={k}={json.dumps(v)}" for k, v in SMALL.items() if k != "runner"]
    code = main(["--config", "async", "--run-dir", str(run_dir), "--no-progress", *sets, "--set=workers=1",
                 "--set=inference=server", "--set=num_envs=2", "--set=total_env_steps=16"])
    assert code == 0
    first = json.loads((run_dir / "summary.json").read_text())
    assert first["runner"] == "async" and first["env_steps"] >= 16 and first["worker_deaths"] == 0
    assert json.loads((run_dir / "config.json").read_text())["inference"] == "server"
    assert list((run_dir / "checkpoints").glob("step_*/meta.json"))
    code = main(["--resume", str(run_dir), "--no-progress", "--set", f"total_env_steps={first['env_steps'] + 16}"])
    assert code == 0
    resumed = json.loads((run_dir / "summary.json").read_text())
    assert resumed["updates"] > first["updates"] and resumed["env_steps"] >= first["env_steps"] + 16
    assert (Path(run_dir) / "policy.safetensors").is_file()


@pytest.mark.parametrize("changes", [
    {"opponent": "snapshot", "snapshot_every_updates": 1},                           # the worker's own weights
    {"teacher": "chaser", "imitation_coef": 1.0, "teacher_driven_worlds": 1},        # teacher rows in the requests
    {"variant": "pred", "privileged_pose_seeding": True, "use_localization": True},  # seeding on the server
    {"scenario": "driving", "players_per_team": 2, "action_mode": "continuous"},     # float actions
], ids=["snapshot", "teacher_driven", "pose_seeding", "driving_continuous"])
def test_every_kind_of_run_trains_with_the_server(tmp_path, changes):
    """What the requests and answers carry besides observations, through the processes: each run learns finite
    losses with nobody dying."""
    cfg = small(workers=1, num_envs=2, total_env_steps=16, inference="server", **changes)
    summary = Trainer(cfg, tmp_path / "run", progress=False).run()
    assert summary["env_steps"] >= 16 and summary["worker_deaths"] == 0 and "stop_reason" not in summary
    with open(tmp_path / "run" / "metrics.csv", newline="") as handle:
        losses = [float(row["value"]) for row in csv.DictReader(handle) if row["name"] == "train/loss"]
    assert losses and all(np.isfinite(losses))
