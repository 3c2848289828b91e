"""Rollout workers as Ray actors (``backend: ray``): the same ``RolloutWorker`` as the process pool's, on an
embedded local Ray or on every node of a cluster (``ray_address``); the learner stays this one process.

Each actor keeps two ``collect`` calls queued (one running, one waiting), each carrying the weights that were the
newest when it was queued (an object-store reference, put once per update); a finished rollout comes back through
the object store as ``rollout_transfer.flatten``'s arrays (read-only views on the learner's node, a copy from
another), and handing it back (``release``) queues the actor's next call — the same backpressure and the same
policy-lag bound as the process pool's slots.

A dead actor or node (``ray.exceptions.RayActorError``: the actor died, or its node did; ``ObjectLostError``: a
finished rollout was lost with its node) loses the rollouts it had in flight, nothing else: it is counted and, while ``worker_restarts`` allow and the cluster has a free CPU, replaced
by a new actor wherever Ray places it; otherwise the run goes on with the actors left, and stops with a one-line
reason when none is left. A Ray task error (the worker's own exception) stops the run with that reason.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any, Callable

import torch

from dynenv_ros.learning.config import TrainConfig
from dynenv_ros.learning.distributed.ray_connection import RayConnectionError, cluster_cpus, connect
from dynenv_ros.learning.distributed.rollout_transfer import unflatten
from dynenv_ros.learning.distributed.rollout_worker import RolloutWorker, resolve_workers, shard_sizes
from dynenv_ros.learning.distributed.shared_weights import pack, unpack
from dynenv_ros.learning.distributed.child_process import one_line
from dynenv_ros.learning.distributed.worker_pool import Delivery, WorkerPoolError, replace_or_go_on

QUEUED_CALLS = 2             # collect calls per actor: one running, one waiting


class RolloutActor:
    """A ``RolloutWorker`` behind Ray's actor interface (wrapped with ``ray.remote`` by the pool)."""

    def __init__(self, cfg_dict: dict[str, Any], index: int, first_world: int, num_envs: int, incarnation: int,
                 first_update: int, league_state: dict[str, Any] | None = None,
                 snapshot_states: list[Any] | None = None) -> None:
        self.worker = RolloutWorker(TrainConfig.from_dict(cfg_dict), index, first_world, num_envs, incarnation,
                                    first_update, league_state=league_state, snapshot_states=snapshot_states)

    def node_id(self) -> str:
        import ray
        return ray.get_runtime_context().get_node_id()

    def collect(self, weights: Any, version: int, env_steps: int) -> tuple[dict[str, Any], dict[str, Any]]:
        if version != self.worker.version:
            unpack(weights, self.worker.networks)
            self.worker.adopt(version)
        arrays, info = self.worker.collect(env_steps)
        info["node"] = self.node_id()
        info["layout_shapes"] = self.worker.layout_shapes
        info["layout_spec"] = self.worker.layout_spec
        return arrays, info


@dataclass
class _Actor:
    index: int
    first_world: int
    num_envs: int
    incarnation: int = 0
    handle: Any = None
    alive: bool = False
    queued: int = 0                                  # collect calls submitted and not yet returned
    nodes: set[str] = field(default_factory=set)


class RayPool:
    """``workers`` Ray actors (default: the cluster's CPUs, less one when the learner's CPU is one of them)."""

    def __init__(self, cfg: TrainConfig, networks: torch.nn.Module, first_update: int,
                 log: Callable[[str], None] = print, first_env_steps: int = 0,
                 league_states: dict[int, dict[str, Any]] | None = None, snapshots: Any = None) -> None:
        self.cfg, self.log, self.first_update = cfg, log, first_update
        self.league_states = league_states if league_states is not None else {}   # as ProcessPool's
        self.snapshots = snapshots
        self.deaths = self.restarts = 0
        self.layout_shapes: dict[str, list[int]] | None = None
        self.layout_spec: Any = None
        self.rollouts_by_node: dict[str, int] = {}
        embedded = cfg.ray_address is None
        if embedded:
            workers = resolve_workers(cfg)
            cpus = workers
        else:
            workers = cfg.workers
            cpus = None
        try:
            self.ray, self._started = connect(cfg.ray_address, cfg.ray_connect_timeout_s, num_cpus=cpus)
        except RayConnectionError as error:
            raise WorkerPoolError(str(error)) from None
        available = cluster_cpus(self.ray)
        if workers is None:
            workers = max(1, min(cfg.num_envs, available))
        if workers > available:
            self.close()
            where = "the embedded Ray" if embedded else f"the Ray cluster at {cfg.ray_address}"
            raise WorkerPoolError(f"workers {workers} need {workers} CPUs, {where} has {available}")
        self._remote = self.ray.remote(num_cpus=1, max_restarts=0)(RolloutActor)
        self._actors = [_Actor(i, a, n) for i, (a, n) in enumerate(shard_sizes(cfg.num_envs, workers))]
        self._calls: dict[Any, int] = {}
        self.publish(networks, first_update)
        self._env_steps = first_env_steps       # the learner's count the actors' next rollouts follow
        for actor in self._actors:
            self._start(actor)

    @property
    def workers(self) -> int:
        return len(self._actors)

    @property
    def alive(self) -> int:
        return sum(a.alive for a in self._actors)

    @property
    def nodes_seen(self) -> set[str]:
        return set(self.rollouts_by_node)

    def _start(self, actor: _Actor) -> None:
        actor.handle = self._remote.remote(self.cfg.to_dict(), actor.index, actor.first_world, actor.num_envs,
                                           actor.incarnation, self.first_update,
                                           self.league_states.get(actor.index),
                                           self.snapshots.states if self.snapshots else None)
        actor.alive, actor.queued = True, 0
        for _ in range(QUEUED_CALLS):
            self._queue(actor)

    def _queue(self, actor: _Actor) -> None:
        reference = actor.handle.collect.remote(self._weights, self._version, self._env_steps)
        self._calls[reference] = actor.index
        actor.queued += 1

    def publish(self, networks: torch.nn.Module, version: int) -> None:
        self._weights = self.ray.put(pack(networks)[0])
        self._version = version

    def _died(self, actor: _Actor, why: str) -> None:
        actor.alive = False
        for reference in [r for r, i in self._calls.items() if i == actor.index]:
            del self._calls[reference]          # its rollouts in flight are lost
        actor.incarnation += 1
        room = self.ray.available_resources().get("CPU", 0.0) >= 1.0
        replace_or_go_on(self, f"rollout worker {actor.index} (Ray actor)", why, lambda: self._start(actor), room)

    def get(self, timeout: float) -> Delivery | None:
        exceptions = self.ray.exceptions
        deadline = time.monotonic() + timeout
        while True:
            if not self._calls:
                raise WorkerPoolError("no rollout worker is running")
            left = max(0.0, deadline - time.monotonic())
            ready, _ = self.ray.wait(list(self._calls), num_returns=1, timeout=left)
            if not ready:
                return None
            reference = ready[0]
            actor = self._actors[self._calls.pop(reference)]
            actor.queued -= 1
            try:
                arrays, info = self.ray.get(reference)
            except (exceptions.RayActorError, exceptions.ObjectLostError) as error:
                # the actor died, or its node did after the rollout was made (the result was lost with the node)
                if actor.alive:
                    self._died(actor, one_line(error).split(". ")[0][:200])
                continue
            except exceptions.RayTaskError as error:
                cause = getattr(error, "cause", None) or error
                raise WorkerPoolError(f"rollout worker {actor.index} failed: {one_line(cause)}") from None
            if self.layout_shapes is None:
                self.layout_shapes, self.layout_spec = info["layout_shapes"], info["layout_spec"]
            actor.nodes.add(info["node"])
            self.rollouts_by_node[info["node"]] = self.rollouts_by_node.get(info["node"], 0) + 1
            # the object store's arrays are read-only views; the learner's tensors get their own copy
            return Delivery(actor.index, None, unflatten({k: v.copy() for k, v in arrays.items()}), info)

    def release(self, delivery: Delivery, env_steps: int) -> None:
        """The learner is done with the rollout: the actor's next call is queued (with the newest weights)."""
        self._env_steps = env_steps
        actor = self._actors[delivery.worker]
        if actor.alive and actor.queued < QUEUED_CALLS:
            self._queue(actor)

    def close(self) -> None:
        ray = getattr(self, "ray", None)
        if ray is None:
            return
        for actor in getattr(self, "_actors", []):
            if actor.handle is not None:
                try:
                    ray.kill(actor.handle)
                except Exception:
                    pass
                actor.handle, actor.alive = None, False
        self._calls = {}
        if getattr(self, "_started", False):
            ray.shutdown()
        self.ray = None
