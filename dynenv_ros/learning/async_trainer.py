"""The asynchronous actor-learner (``runner: async``): rollout workers step the worlds and act while this process
learns, so neither the simulation nor the learner waits for the other (Sample Factory's APPO, IMPALA's split).

- Workers (``worker_pool``: processes of this machine; ``ray_pool``: Ray actors, local or on a cluster) each run
  ``RolloutWorker`` over their share of ``num_envs`` worlds with the weights they last received.
- The learner takes ``rollouts_per_update`` rollouts as they come, joins them along the robot axis, runs the same
  ``algorithms.update`` as the in-process trainer, then publishes its weights (version = its update count) and hands
  the slots back.
- Policy lag is bounded and corrected: a rollout acted with weights more than ``max_policy_lag`` updates old is
  dropped (counted, ``async/dropped_rollouts``); within it, PPO's clipped ratio is taken against the behaviour
  log-probabilities the worker stored, and the advantages use the behaviour values (as PPO does after its first
  epoch). The lag of every rollout learnt from is logged (``async/policy_lag``, ``async/policy_lag_max``).
- Env steps count what the learner learnt from; ``async/env_steps_generated_per_second`` counts what the workers
  made (dropped rollouts included).

Everything else is the in-process trainer's: networks, optimiser, losses, checkpoints (the workers hold no state
worth keeping: after ``--resume`` or a SIGKILL they start fresh episodes, as the in-process worlds do), logs,
curves, the shipped policy. Why not the trainer node's ``SequenceLearner``: it rebuilds sequences from per-robot
messages and chains their recurrent states across batches; a worker's rollout arrives whole with its start state,
which is exactly what ``update`` takes.
"""
from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

from dynenv_ros.learning.config import TrainConfig
from dynenv_ros.learning.distributed.rollout_transfer import join
from dynenv_ros.learning.distributed.rollout_worker import resolve_workers
from dynenv_ros.learning.trainer import Experience, Trainer
from dynenv_ros.learning.distributed.worker_pool import Delivery, WorkerPoolError

WAIT_POLL_S = 1.0            # how often a waiting learner checks its deadline and its workers


class AsyncTrainer(Trainer):
    """``Trainer`` whose experience comes from rollout workers (module docstring); same run directory."""

    wait_scalar = "speed/learner_wait_seconds_per_update"

    def __init__(self, cfg: TrainConfig, run_dir: str | Path, resume: bool = False, progress: bool = True,
                 log: Any = None) -> None:
        if cfg.runner != "async":
            raise ValueError("AsyncTrainer runs configs with runner: async")
        self._log_line = log or (lambda line: print(f"dynenv-train: {line}", file=sys.stderr, flush=True))
        self.pool: Any = None
        self.dropped = 0
        self.generated_steps = 0
        super().__init__(cfg, run_dir, resume=resume, progress=progress)

    def _start_rollouts(self) -> None:
        self.env = self.collector = self.opponent = None
        cfg = self.cfg
        if cfg.backend == "ray":
            from dynenv_ros.learning.distributed.ray_pool import RayPool
            self.pool = RayPool(cfg, self.learner, first_update=self.updates, log=self._log_line)
        else:
            from dynenv_ros.learning.distributed.worker_pool import ProcessPool
            self.pool = ProcessPool(cfg, self.learner, resolve_workers(cfg), first_update=self.updates,
                                    log=self._log_line)
        self.layout_shapes = None       # known once a worker said hello (set in _experience)

    def _experience(self, deadline: float) -> Experience | None:
        cfg = self.cfg
        deliveries: list[Delivery] = []
        try:
            while len(deliveries) < cfg.rollouts_per_update:
                if self._elapsed() >= deadline:
                    for delivery in deliveries:
                        self.pool.release(delivery, self.env_steps)
                    return None
                delivery = self.pool.get(timeout=WAIT_POLL_S)
                if delivery is None:
                    continue
                self.generated_steps += int(delivery.info["env_steps"])
                if self.updates - int(delivery.info["version"]) > cfg.max_policy_lag:
                    self.dropped += 1
                    self.pool.release(delivery, self.env_steps)
                    continue
                deliveries.append(delivery)
        except WorkerPoolError:
            for delivery in deliveries:
                self.pool.release(delivery, self.env_steps)
            raise
        if self.layout_shapes is None:
            self.layout_shapes = self.pool.layout_shapes
            if self.pool.layout_spec is not None:
                self.learner.agent.layout_spec = self.pool.layout_spec
        lags = [self.updates - int(d.info["version"]) for d in deliveries]
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
        return Experience(join([d.rollout for d in deliveries]), sum(int(d.info["env_steps"]) for d in deliveries),
                          finished, scalars)

    def _learned(self, batch: Experience) -> None:
        """Publish the new weights first, then hand the slots back: a worker that waited starts with them."""
        self.pool.publish(self.learner, self.updates)
        for delivery in self._pending:
            self.pool.release(delivery, self.env_steps)
        self._pending = []

    def run(self) -> dict[str, Any]:
        self._pending: list[Delivery] = []
        try:
            return super().run()
        except WorkerPoolError as error:
            # the workers cannot go on: keep what was learnt (checkpoint, policy) and say why, in one line
            self._log_line(f"stopping: {error}")
            self.stop_reason = str(error)
            return self.finish()
        finally:
            self._stop_rollouts()

    def finish(self) -> dict[str, Any]:
        if self.layout_shapes is None:          # no rollout ever arrived: the layout from a one-world env
            from dynenv_ros.learning.sampling.worlds import make_env
            env, _ = make_env(self.cfg, 1, "inprocess")
            self.layout_shapes = {k: list(v) for k, v in env.layout.shapes().items()}
            env.close()
        return super().finish()

    def _summary(self) -> dict[str, Any]:
        summary = super()._summary()
        summary.update({"runner": "async", "dropped_rollouts": self.dropped,
                        "worker_deaths": self.pool.deaths if self.pool is not None else 0,
                        "env_steps_generated": self.generated_steps})
        if getattr(self.pool, "rollouts_by_node", None) is not None:
            summary["rollouts_by_node"] = dict(self.pool.rollouts_by_node)
        if getattr(self, "stop_reason", None):
            summary["stop_reason"] = self.stop_reason
        return summary

    def _stop_rollouts(self) -> None:
        if self.pool is not None:
            for delivery in getattr(self, "_pending", []):
                self.pool.release(delivery, self.env_steps)
            self._pending = []
            self.pool.close()
