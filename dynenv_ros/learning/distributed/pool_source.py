"""Experience from rollout workers (``runner: async``): ``worker_pool.ProcessPool`` (processes of this machine) or
``ray_pool.RayPool`` (Ray actors, local or on a cluster) step the worlds and act while the learner learns, so neither
the simulation nor the learner waits for the other (Sample Factory's APPO, IMPALA's split). An
``ExperienceSource`` (``algo.experience``) of the training loop.

- Each update takes ``rollouts_per_update`` rollouts as they come, joined along the robot axis.
- Policy lag is bounded: a rollout acted with weights more than ``max_policy_lag`` updates old is dropped (counted,
  ``async/dropped_rollouts``); within it the update corrects for the lag (``UpdateSettings.proximal``). The lag of
  every rollout learnt from is logged (``async/policy_lag``, ``async/policy_lag_max``).
- After each update the new weights are published (version = the update count) before the rollouts' slots are
  handed back, so a worker that waited starts with them.
- Env steps count what the learner learnt from; ``env_steps_generated`` (in the summary) also counts dropped
  rollouts.

The workers hold nothing worth checkpointing but a league run's league: after ``--resume`` or a SIGKILL they start
fresh episodes, as the in-process worlds do, and each worker's league carries on from its last delivery's
``league_states``, which the trainer checkpoints, as it does the snapshot opponent's pool (``snapshots``: the
learner's ``run.snapshot_history``, handed to every worker that starts).
"""
from __future__ import annotations

import time
from typing import Any, Callable

import torch

from dynenv_ros.learning.algo.experience import Experience, Progress
from dynenv_ros.learning.algo.networks import TrainingNetworks
from dynenv_ros.learning.config import TrainConfig
from dynenv_ros.learning.distributed.rollout_transfer import join
from dynenv_ros.learning.distributed.rollout_worker import resolve_workers
from dynenv_ros.learning.distributed.worker_pool import Delivery, WorkerPoolError

COUNTS = ("dropped_rollouts", "worker_deaths", "env_steps_generated")     # summed over a run's segments
WAIT_POLL_S = 1.0            # how often a waiting learner checks its deadline and its workers


class PoolSource:
    """The workers of ``cfg.backend`` (``ray``: Ray actors; else processes), started at once with the networks'
    weights; ``WorkerPoolError`` from ``next`` when they cannot go on."""

    # what the time before each update is: the learner waiting for rollouts
    wait_scalar = "speed/learner_wait_seconds_per_update"

    def __init__(self, cfg: TrainConfig, networks: TrainingNetworks, first_update: int, device: torch.device,
                 log: Callable[[str], None], first_env_steps: int = 0,
                 league_states: dict[int, dict[str, Any]] | None = None,
                 earlier_counts: dict[str, int] | None = None, snapshots: Any = None) -> None:
        self.cfg, self.networks, self.device = cfg, networks, device
        # a resumed run's counts before this segment (``counts``, from its checkpoint), so the summary is the run's
        self.earlier = {key: int((earlier_counts or {}).get(key, 0)) for key in COUNTS}
        # worker index -> its league (League.state) as last delivered: the pool starts workers with it
        self.league_states: dict[int, dict[str, Any]] = dict(league_states or {})
        self.dropped = 0
        self.generated_steps = 0
        self.layout_shapes: dict[str, list[int]] | None = None      # known once a worker said hello
        self._pending: list[Delivery] = []
        # the learner's count, which the workers' teacher-driven worlds and curriculum stage follow
        self._env_steps = first_env_steps
        self.pool: Any = None
        if cfg.backend == "ray":
            from dynenv_ros.learning.distributed.ray_pool import RayPool
            self.pool = RayPool(cfg, networks, first_update=first_update, log=log, first_env_steps=first_env_steps,
                                league_states=self.league_states, snapshots=snapshots)
        else:
            from dynenv_ros.learning.distributed.worker_pool import ProcessPool
            self.pool = ProcessPool(cfg, networks, resolve_workers(cfg), first_update=first_update, log=log,
                                    first_env_steps=first_env_steps, league_states=self.league_states,
                                    snapshots=snapshots)

    def next(self, progress: Progress, deadline: float) -> Experience | None:
        """``rollouts_per_update`` fresh rollouts joined; None when the deadline passes while waiting for them."""
        cfg = self.cfg
        self._env_steps = progress.env_steps
        deliveries: list[Delivery] = []
        try:
            while len(deliveries) < cfg.rollouts_per_update:
                if time.perf_counter() >= deadline:
                    for delivery in deliveries:
                        self.pool.release(delivery, progress.env_steps)
                    return None
                delivery = self.pool.get(timeout=WAIT_POLL_S)
                if delivery is None:
                    continue
                self.generated_steps += int(delivery.info["env_steps"])
                if delivery.info.get("league_state") is not None:
                    self.league_states[int(delivery.info["worker"])] = delivery.info["league_state"]
                if progress.updates - int(delivery.info["version"]) > cfg.max_policy_lag:
                    self.dropped += 1
                    self.pool.release(delivery, progress.env_steps)
                    continue
                deliveries.append(delivery)
        except WorkerPoolError:
            for delivery in deliveries:
                self.pool.release(delivery, progress.env_steps)
            raise
        if self.layout_shapes is None:
            self.layout_shapes = self.pool.layout_shapes
            if self.pool.layout_spec is not None:
                self.networks.agent.layout_spec = self.pool.layout_spec
        lags = [progress.updates - int(d.info["version"]) for d in deliveries]
        finished = [episode for d in deliveries for episode in d.info["finished"]]
        self._pending = deliveries
        scalars = {"async/policy_lag": float(sum(lags) / len(lags)), "async/policy_lag_max": float(max(lags)),
                   "async/dropped_rollouts": float(self.dropped), "async/worker_deaths": float(self.pool.deaths),
                   "async/workers_alive": float(self.pool.alive),
                   "async/worker_collect_seconds": float(sum(d.info["collect_seconds"] for d in deliveries)
                                                         / len(deliveries))}
        for key in deliveries[0].info.get("league", {}):      # a league run: each worker's own league, averaged
            scalars[key] = float(sum(d.info["league"].get(key, 0.0) for d in deliveries) / len(deliveries))
        nodes = getattr(self.pool, "nodes_seen", None)
        if nodes is not None:                   # Ray: the cluster nodes whose actors delivered so far
            scalars["async/nodes_seen_max"] = float(len(nodes))
        rollout = join([d.rollout for d in deliveries])
        return Experience(rollout.as_tensors(self.device), sum(int(d.info["env_steps"]) for d in deliveries),
                          finished, scalars)

    def learned(self, progress: Progress) -> None:
        """Publish the new weights first, then hand the slots back: a worker that waited starts with them."""
        self._env_steps = progress.env_steps
        self.pool.publish(self.networks, progress.updates)
        for delivery in self._pending:
            self.pool.release(delivery, progress.env_steps)
        self._pending = []

    def counts(self) -> dict[str, int]:
        """The run's dropped rollouts, worker deaths and env steps generated, earlier segments included."""
        now = {"dropped_rollouts": self.dropped, "worker_deaths": self.pool.deaths if self.pool is not None else 0,
               "env_steps_generated": self.generated_steps}
        return {key: self.earlier[key] + int(now[key]) for key in COUNTS}

    def summary(self) -> dict[str, Any]:
        """What the run's summary adds of the workers (over the whole run, ``--resume``d segments included)."""
        summary: dict[str, Any] = {"runner": "async", **self.counts()}
        if getattr(self.pool, "rollouts_by_node", None) is not None:
            summary["rollouts_by_node"] = dict(self.pool.rollouts_by_node)
        return summary

    def close(self) -> None:
        if self.pool is not None:
            for delivery in self._pending:
                self.pool.release(delivery, self._env_steps)
            self._pending = []
            self.pool.close()
