"""A rollout worker of the asynchronous runner: its share of the run's worlds, the opponent, and an acting copy of
the learner's networks, producing one rollout at a time with whatever weights it was last given. Transport-free:
``worker_pool`` runs it in a worker process (shared memory), ``ray_pool`` in a Ray actor (object store).

Seeds: a worker's worlds, action sampling and random draws come from ``SeedSequence([seed, worker, incarnation,
first update])``, so a worker that replaces a dead one, or starts after a resume, plays fresh episodes. A run of
this runner is not bit-reproducible (which weights a rollout acts with depends on timing); its seeds still make
every world's episodes independent and every worker's draws its own.

With ``inference: server`` the worker acts through the inference server (``server``: its pipe to it), which draws
the learning robots' actions from a generator of the seed the worker's own acting would use; the worker's own
generator, which a snapshot opponent draws from, then takes a fifth child seed, so that the two never share draws.
"""
from __future__ import annotations

import dataclasses
import os
import time
from multiprocessing.connection import Connection
from typing import Any, Mapping

import numpy as np
import torch

from dynenv_ros.learning.algo.networks import make_agent
from dynenv_ros.learning.config import TrainConfig
from dynenv_ros.learning.algo.networks import TrainingNetworks
from dynenv_ros.learning.distributed.inference_server import ServerActing
from dynenv_ros.learning.distributed.rollout_transfer import flatten
from dynenv_ros.learning.sampling.worlds import Worlds, follow_curriculum, make_worlds, teacher_driven_share


def usable_cores() -> int:
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)


def resolve_workers(cfg: TrainConfig, cores: int | None = None) -> int:
    """``cfg.workers``, or one per core this process may use, less one for a CPU learner and one for the inference
    server (``inference: server``); at most ``num_envs``; at least one per team size (``team_sizes``: each worker
    plays one size)."""
    if cfg.workers is not None:
        return cfg.workers
    cores = usable_cores() if cores is None else cores
    wanted = cores - (cfg.device == "cpu") - (cfg.inference == "server")
    return max(1, len(cfg.team_sizes or ()), min(cfg.num_envs, wanted))


def worker_config(cfg: TrainConfig, index: int) -> TrainConfig:
    """The config worker ``index`` plays: with ``team_sizes``, its size is the (index mod sizes)-th, so the sizes
    alternate over the workers and every rollout of one worker has one shape (its slots' shape)."""
    if not cfg.team_sizes:
        return cfg
    return dataclasses.replace(cfg, players_per_team=cfg.team_sizes[index % len(cfg.team_sizes)])


def shard_sizes(num_envs: int, workers: int) -> list[tuple[int, int]]:
    """(first world, worlds) of each worker: ``num_envs`` split as evenly as possible, the larger shares first."""
    sizes = [num_envs // workers + (1 if w < num_envs % workers else 0) for w in range(workers)]
    starts = np.concatenate([[0], np.cumsum(sizes)[:-1]])
    return [(int(a), int(n)) for a, n in zip(starts, sizes)]


class RolloutWorker:
    """Builds its worlds once it holds the learner's weights (a snapshot opponent starts as a copy of them);
    ``league_state``: the league this worker's worlds carry on (a resumed run's, or a dead worker's last, as its
    deliveries reported it; ``League.state``); ``snapshot_states``: the snapshot opponent's pool to start from (the
    learner's, ``run.snapshot_history``; default: a copy of the weights it is first given)."""

    def __init__(self, cfg: TrainConfig, index: int, first_world: int, num_envs: int, incarnation: int = 0,
                 first_update: int = 0, server: Connection | None = None,
                 league_state: dict[str, Any] | None = None,
                 snapshot_states: list[dict[str, np.ndarray]] | None = None) -> None:
        cfg = worker_config(cfg, index)
        self.cfg, self.index, self.first_world, self.num_envs = cfg, index, first_world, num_envs
        torch.set_num_threads(1)                # one core per worker: intra-op threads would fight the others
        seeds = np.random.SeedSequence([cfg.seed, index, incarnation, first_update]).spawn(5)
        self.acting_seed = int(seeds[0].generate_state(1)[0])       # the learning robots' draws, here or served
        self.server = server
        own = self.acting_seed if server is None else int(seeds[4].generate_state(1)[0])
        self.generator = torch.Generator().manual_seed(own)
        self.rng = np.random.default_rng(seeds[1])
        self.world_seed = int(seeds[2].generate_state(1)[0])
        torch.manual_seed(int(seeds[3].generate_state(1)[0]))   # parameter init only, overwritten by the weights
        self.networks = TrainingNetworks(make_agent(cfg), cfg.ltp_horizon).eval()
        for parameter in self.networks.parameters():
            parameter.requires_grad_(False)
        self.version = -1                       # the learner's update count of the weights acted with
        self.worlds: Worlds | None = None
        self._snapshots = 0
        self.league_state = league_state
        self.snapshot_states = snapshot_states
        self._cpu_started = time.process_time()

    @property
    def layout_shapes(self) -> dict[str, list[int]]:
        self._ensure_worlds(0)
        return {k: list(v) for k, v in self.worlds.env.layout.shapes().items()}

    @property
    def layout_spec(self) -> Any:
        return getattr(self.networks.agent, "layout_spec", None)

    def adopt(self, version: int) -> None:
        """The weights now in ``self.networks`` are the learner's after ``version`` updates. A snapshot opponent takes
        a copy every ``snapshot_every_updates`` updates, as the in-process trainer's does."""
        if version == self.version:
            return
        self.version = version
        if self.worlds is not None and self.cfg.opponent in ("snapshot", "league"):
            due = version // self.cfg.snapshot_every_updates
            if due > self._snapshots:
                self.worlds.opponent.refresh(self.networks.agent)
                self._snapshots = due

    def _ensure_worlds(self, env_steps: int) -> None:
        """The worlds, made on first use; their first episodes start in the curriculum stage of ``env_steps``."""
        if self.worlds is None:
            if self.version < 0:
                raise RuntimeError("a rollout worker needs the learner's weights before its first rollout")
            self._snapshots = self.version // self.cfg.snapshot_every_updates
            self.worlds = make_worlds(self.cfg, self.networks, self.num_envs, "inprocess", self.generator, self.rng,
                                      seed=self.world_seed, acting=self._served if self.server is not None else None,
                                      env_steps=env_steps)
            if self.snapshot_states and self.cfg.opponent in ("snapshot", "league"):
                self.worlds.opponent.load_pool(self.snapshot_states)
            if self.league_state is not None and self.cfg.opponent == "league":
                self.worlds.env.start_league_from(self.league_state)

    def _served(self, obs: Mapping[str, np.ndarray], with_teacher: bool, seeding: bool) -> ServerActing:
        """The collector's acting on the inference server (registered with this worker's first observations)."""
        assert self.server is not None
        return ServerActing(self.server, self.acting_seed, self.networks.agent, obs, with_teacher, seeding)

    def collect(self, env_steps: int) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        """The next rollout (``flatten``'s arrays) and what the learner logs of it; ``env_steps``: the learner's count,
        which decides the teacher-driven worlds and the curriculum stage of the worlds' next episodes."""
        self._ensure_worlds(env_steps)
        collector = self.worlds.collector
        collector.drive_with_teacher(teacher_driven_share(self.cfg, env_steps, self.first_world, self.num_envs))
        follow_curriculum(self.worlds, self.cfg, env_steps)
        started = time.perf_counter()
        served = collector.acting if isinstance(collector.acting, ServerActing) else None
        if served is not None:
            served.oldest = None
        rollout = collector.collect(self.cfg.rollout_length)
        finished, collector.finished = collector.finished, []
        # acted with: the weights loaded here, or the oldest the server answered with during the rollout
        version = self.version if served is None or served.oldest is None else served.oldest
        info = {"version": version, "worker": self.index, "env_steps": self.num_envs * self.cfg.rollout_length,
                "finished": finished, "collect_seconds": time.perf_counter() - started,
                "cpu_seconds": time.process_time() - self._cpu_started, "pid": os.getpid(),
                "league": self.worlds.env.league_stats() if self.cfg.opponent == "league" else {},
                "league_state": self.worlds.env.league_state() if self.cfg.opponent == "league" else None,
                "curriculum_stage": self.worlds.stage}
        return flatten(rollout), info

    def close(self) -> None:
        if self.worlds is not None:
            self.worlds.collector.close()
            self.worlds.env.close()
            self.worlds = None
        if self.server is not None:
            self.server.close()
            self.server = None
