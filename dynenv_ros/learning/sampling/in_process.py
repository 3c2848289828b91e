"""Experience collected in this process (``runner: sync``): the run's worlds stepped by the current policy, one
rollout per update (the worlds' physics may run in the vector env's worker processes, ``backend``). An
``ExperienceSource`` (``algo.experience``) of the training loop.
"""
from __future__ import annotations

from typing import Any, Callable

import torch

from dynenv_ros.learning.algo.experience import Experience, Progress
from dynenv_ros.learning.algo.networks import TrainingNetworks
from dynenv_ros.learning.config import TrainConfig
from dynenv_ros.learning.sampling.worlds import follow_curriculum, make_worlds, teacher_driven_share


class InProcessSource:
    """``num_envs`` worlds, the opponent and the collector, made at once; each ``next`` collects
    ``rollout_length`` periods of every world with the networks as they are."""

    # what the time before each update is: collecting
    wait_scalar = "speed/rollout_seconds_per_update"

    def __init__(self, cfg: TrainConfig, networks: TrainingNetworks, generator: torch.Generator, rng: Any, seed: int,
                 device: torch.device, env_steps: int = 0, league_state: dict[str, Any] | None = None,
                 log: Callable[[str], None] = print, snapshot_states: list[Any] | None = None) -> None:
        self.cfg, self.networks, self.device = cfg, networks, device
        self.worlds = worlds = make_worlds(cfg, networks, cfg.num_envs, cfg.backend, generator, rng, seed=seed,
                                           env_steps=env_steps)
        self.env, self.opponent, self.collector = worlds.env, worlds.opponent, worlds.collector
        if snapshot_states and cfg.opponent in ("snapshot", "league"):      # a resumed run's pool
            self.opponent.load_pool(snapshot_states)
        if league_state is not None and cfg.opponent == "league":
            try:
                self.env.start_league_from(league_state)
            except ValueError as error:     # e.g. resumed with the worlds in worker processes: they keep their own
                log(f"the checkpoint's league is not carried on ({error}); it starts again from even scores")
        self.layout_shapes: dict[str, list[int]] | None = {k: list(v) for k, v in self.env.layout.shapes().items()}
        self._closed = False

    def next(self, progress: Progress, deadline: float) -> Experience:
        """The next rollout, collected here by the current policy (the deadline does not cut a rollout short)."""
        cfg = self.cfg
        self.networks.eval()
        self.collector.drive_with_teacher(teacher_driven_share(cfg, progress.env_steps, 0, cfg.num_envs))
        follow_curriculum(self.worlds, cfg, progress.env_steps)
        rollout = self.collector.collect(cfg.rollout_length)
        finished, self.collector.finished = self.collector.finished, []
        return Experience(rollout.as_tensors(self.device), cfg.num_envs * cfg.rollout_length, finished,
                          self.env.league_stats())

    def learned(self, progress: Progress) -> None:
        """A snapshot opponent takes its copy every ``snapshot_every_updates``."""
        if self.opponent is not None and self.cfg.opponent in ("snapshot", "league") \
                and progress.updates % self.cfg.snapshot_every_updates == 0:
            self.opponent.refresh(self.networks.agent)

    @property
    def league_states(self) -> dict[int, dict[str, Any]]:
        """A league run's league (as ``PoolSource``'s, one 'worker': this process), to checkpoint; {} otherwise."""
        state = self.env.league_state() if self.cfg.opponent == "league" else None
        return {} if state is None else {0: state}

    def summary(self) -> dict[str, Any]:
        """What the run's summary adds of this source: nothing."""
        return {}

    def close(self) -> None:
        if not self._closed:
            self._closed = True
            self.env.close()
