"""Rollout workers in processes of this machine, for the asynchronous runner: each steps its share of the worlds
(``RolloutWorker``) and writes each rollout into one of its slots of shared memory; the learner reads the slot in
place, learns, and hands the slot back. Weights travel the other way through one shared block (``SharedWeights``).

The pipe of each worker carries only small messages (a slot's number, episode statistics), never a rollout:

    worker → learner   ("hello", spec, layout shapes, layout spec)   after its first rollout: what a slot must hold
                       ("ready", slot, info)                         a rollout is in the slot
                       ("error", reason, traceback)                  it failed and stops
    learner → worker   ("slots", names, free slots)                  the answer to hello
                       ("free", slot, env steps)                     the learner is done with the slot
                       ("stop",)

With ``inference: server`` the pool also starts the inference server (``inference_server``) before the workers and
gives each worker (and each replacement) a pipe of its own to it; a server that fails or dies stops the run with
its reason, whatever the workers then report.

Why per-worker pipes and slots, not shared queues: a worker killed while it holds a queue's lock leaves the lock
held for everyone; a dead worker here breaks only its own pipe, which the learner sees as end-of-file. Its slots
stay allocated, and the worker that replaces it (``worker_restarts``) takes them over. Workers die with the
learner (``PR_SET_PDEATHSIG``), ignore Ctrl-C (the learner stops them), and leave no shared memory behind (the
learner created every block and unlinks it on ``close``; after a SIGKILL, multiprocessing's resource tracker does).
"""
from __future__ import annotations

import math
import multiprocessing as mp
import time
import traceback
from dataclasses import dataclass, field
from multiprocessing.connection import Connection, wait
from typing import Any, Callable

import torch

from dynenv_ros.learning.config import TrainConfig
from dynenv_ros.learning.algo.experience import Rollout
from dynenv_ros.learning.distributed.child_process import die_with_parent, one_line
from dynenv_ros.learning.distributed.inference_server import InferenceServer, InferenceServerError
from dynenv_ros.learning.distributed.rollout_transfer import AttachedSlots, RolloutSlots, spec_of
from dynenv_ros.learning.distributed.rollout_worker import RolloutWorker, shard_sizes
from dynenv_ros.learning.distributed.shared_weights import AttachedWeights, SharedWeights

HELLO_TIMEOUT_S = 300.0       # a worker builds its worlds and collects its first rollout within this


class WorkerPoolError(RuntimeError):
    """The rollout workers cannot go on; the message is one line saying why."""


@dataclass
class Delivery:
    """A rollout handed to the learner: its arrays (views of shared memory until ``release``) and its info."""
    worker: int
    slot: int | None
    rollout: Rollout
    info: dict[str, Any]


def replace_or_go_on(pool: Any, label: str, why: str, replace: Callable[[], None], room: bool = True) -> None:
    """After a worker's death (counted here): replace it while ``worker_restarts`` allow and there is ``room``;
    otherwise go on with the workers left (logged), or raise WorkerPoolError when none is left. ``pool``: the
    process or Ray pool (``cfg``, ``deaths``, ``restarts``, ``alive``, ``workers``, ``log``)."""
    pool.deaths += 1
    restarts_left = pool.restarts < pool.cfg.worker_restarts
    if restarts_left and room:
        pool.restarts += 1
        pool.log(f"{label} died: {why}; starting a replacement ({pool.restarts} of {pool.cfg.worker_restarts} "
                 f"restarts used)")
        replace()
        return
    reason = "no free CPU for a replacement" if restarts_left else \
        f"no restarts left (worker_restarts={pool.cfg.worker_restarts})"
    if pool.alive == 0:
        raise WorkerPoolError(f"every rollout worker is dead (last: {label}, {why}); {reason}")
    pool.log(f"{label} died: {why}; {reason}, going on with {pool.alive} of {pool.workers}")


def worker_main(conn: Connection, cfg_dict: dict[str, Any], index: int, first_world: int, num_envs: int,
                incarnation: int, first_update: int, weights_names: dict[str, Any],
                server: Connection | None = None, first_env_steps: int = 0,
                league_state: dict[str, Any] | None = None, snapshot_states: list[Any] | None = None) -> None:
    """A worker process: its first rollout, the handshake, then rollouts into free slots until told to stop
    (``server``: its pipe to the inference server, with ``inference: server``; ``first_env_steps``: the learner's
    count when the pool started, e.g. a resumed run's, until the learner sends a newer one; ``league_state``: the
    league its worlds carry on; ``snapshot_states``: the snapshot opponent's pool to start from)."""
    die_with_parent()
    worker = slots = weights = None
    try:
        cfg = TrainConfig.from_dict(cfg_dict)
        worker = RolloutWorker(cfg, index, first_world, num_envs, incarnation, first_update, server, league_state,
                               snapshot_states)
        weights = AttachedWeights(weights_names, worker.networks)
        worker.adopt(weights.load_into(worker.networks, -1))
        env_steps = first_env_steps
        arrays, info = worker.collect(env_steps)
        conn.send(("hello", spec_of(arrays), worker.layout_shapes, worker.layout_spec))
        _, names, free = conn.recv()
        slots = AttachedSlots(names)
        free = list(free)
        while True:
            while not free or conn.poll():
                message = conn.recv()
                if message[0] == "stop":
                    return
                if message[0] == "free":
                    free.append(message[1])
                    env_steps = max(env_steps, int(message[2]))
            slot = free.pop(0)
            slots.write(slot, arrays)
            conn.send(("ready", slot, info))
            worker.adopt(weights.load_into(worker.networks, worker.version))
            arrays, info = worker.collect(env_steps)
    except (EOFError, BrokenPipeError, ConnectionResetError):
        return                                  # the learner is gone or closed the pipe
    except BaseException as error:              # report, then stop: the learner decides
        try:
            conn.send(("error", one_line(error), traceback.format_exc()))
        except OSError:
            pass
    finally:
        for thing in (slots, weights, worker):
            if thing is not None:
                try:
                    thing.close()
                except Exception:
                    pass


@dataclass
class _Handle:
    index: int
    first_world: int
    num_envs: int
    incarnation: int = 0
    process: Any = None
    conn: Connection | None = None
    slots: RolloutSlots | None = None
    held: set[int] = field(default_factory=set)     # slots the learner holds (delivered, not released)
    started: float = 0.0
    ready: bool = False                              # said hello
    alive: bool = False


class ProcessPool:
    """``workers`` worker processes over ``cfg.num_envs`` worlds; ``get`` returns the next rollout.
    ``league_states``: worker index → the league it carries on, and ``snapshots``: the learner's snapshot pool
    (``run.snapshot_history``), both read whenever a worker starts, a replacement included."""

    def __init__(self, cfg: TrainConfig, networks: torch.nn.Module, workers: int, first_update: int,
                 log: Callable[[str], None] = print, first_env_steps: int = 0,
                 league_states: dict[int, dict[str, Any]] | None = None, snapshots: Any = None) -> None:
        self.cfg, self.log = cfg, log
        self.league_states = league_states if league_states is not None else {}
        self.snapshots = snapshots
        self.first_update = first_update
        self._env_steps = first_env_steps        # the learner's count last sent: a replacement worker starts there
        self.slots_per_worker = max(2, math.ceil(cfg.rollouts_per_update / workers) + 1)
        self.deaths = self.restarts = 0
        self.layout_shapes: dict[str, list[int]] | None = None
        self.layout_spec: Any = None
        self._context = mp.get_context("spawn")
        self._weights = SharedWeights(networks)
        self._weights.publish(networks, first_update)
        self._handles = [_Handle(i, a, n) for i, (a, n) in enumerate(shard_sizes(cfg.num_envs, workers))]
        self.server: InferenceServer | None = None
        try:
            if cfg.inference == "server":
                self.server = InferenceServer(cfg, self._weights.names(), self._context)
            for handle in self._handles:
                self._start(handle)
        except BaseException:
            self.close()
            raise

    # -- workers ----------------------------------------------------------------------------------------------
    def _start(self, handle: _Handle) -> None:
        served = None
        if self.server is not None:
            try:
                served = self.server.connect(handle.index)
            except InferenceServerError as error:
                raise WorkerPoolError(str(error)) from None
        parent, child = self._context.Pipe()
        process = self._context.Process(
            target=worker_main, name=f"dynenv-rollout-{handle.index}", daemon=True,
            args=(child, self.cfg.to_dict(), handle.index, handle.first_world, handle.num_envs, handle.incarnation,
                  self.first_update, self._weights.names(), served, self._env_steps,
                  self.league_states.get(handle.index), self.snapshots.states if self.snapshots else None))
        process.start()
        child.close()
        if served is not None:
            served.close()                     # the worker's now: the server's death must reach it as end of file
        handle.process, handle.conn, handle.started = process, parent, time.monotonic()
        handle.ready, handle.alive = False, True

    @property
    def workers(self) -> int:
        return len(self._handles)

    @property
    def alive(self) -> int:
        return sum(h.alive for h in self._handles)

    def pids(self) -> list[int]:
        """The live workers' processes and the inference server's (their CPU time is the rollouts')."""
        return [h.process.pid for h in self._handles if h.alive] + ([self.server.pid] if self.server else [])

    def _check_server(self, wait_s: float = 0.0) -> None:
        """WorkerPoolError with the server's reason once it failed or died (``inference: server``)."""
        if self.server is not None:
            try:
                self.server.check(wait_s)
            except InferenceServerError as error:
                raise WorkerPoolError(str(error)) from None

    def _died(self, handle: _Handle, why: str) -> None:
        """Count a dead worker and replace it while restarts are left; stop the run when none is left alive."""
        handle.alive = False
        if handle.conn is not None:
            handle.conn.close()
            handle.conn = None
        if handle.process is not None:
            handle.process.join(timeout=1.0)
            code = handle.process.exitcode
            why = f"{why} (exit code {code})" if code is not None else why
        handle.incarnation += 1
        replace_or_go_on(self, f"rollout worker {handle.index}", why, lambda: self._start(handle))

    def _hello(self, handle: _Handle, spec: dict[str, Any], shapes: dict[str, list[int]], layout_spec: Any) -> None:
        if handle.slots is None:
            handle.slots = RolloutSlots(spec, self.slots_per_worker)
        elif handle.slots.spec != spec:
            raise WorkerPoolError(f"rollout worker {handle.index}'s replacement makes rollouts of another shape")
        if self.layout_shapes is None:
            self.layout_shapes, self.layout_spec = shapes, layout_spec
        free = [s for s in range(len(handle.slots)) if s not in handle.held]
        handle.conn.send(("slots", handle.slots.names(), free))
        handle.ready = True

    # -- the learner's side -----------------------------------------------------------------------------------
    def publish(self, networks: torch.nn.Module, version: int) -> None:
        self._weights.publish(networks, version)

    def get(self, timeout: float) -> Delivery | None:
        """The next rollout any worker finished, or None after ``timeout`` seconds. Handles handshakes and deaths on
        the way; WorkerPoolError when a worker fails or none is left."""
        deadline = time.monotonic() + timeout
        while True:
            self._check_server()
            conns = {h.conn: h for h in self._handles if h.alive and h.conn is not None}
            if not conns:
                raise WorkerPoolError("no rollout worker is running")
            left = deadline - time.monotonic()
            watched = list(conns) + ([self.server.control] if self.server is not None else [])
            for conn in wait(watched, timeout=max(0.0, left)):
                if conn not in conns:            # the server said something: it failed, or its pipe closed
                    self._check_server(wait_s=1.0)
                    continue
                handle = conns[conn]
                try:
                    message = conn.recv()
                except (EOFError, OSError):
                    self._check_server(wait_s=0.2)
                    self._died(handle, "its pipe closed")
                    continue
                kind = message[0]
                if kind == "ready":
                    slot = message[1]
                    handle.held.add(slot)
                    return Delivery(handle.index, slot, handle.slots.read(slot), message[2])
                if kind == "hello":
                    self._hello(handle, *message[1:])
                elif kind == "error":
                    self._check_server(wait_s=2.0 if InferenceServerError.__name__ in message[1] else 0.0)
                    raise WorkerPoolError(f"rollout worker {handle.index} failed: {message[1]}")
            for handle in self._handles:         # a worker that never said hello, or died without closing its pipe
                if handle.alive and not handle.process.is_alive():
                    self._check_server(wait_s=0.2)
                    self._died(handle, "its process ended")
                elif handle.alive and not handle.ready and time.monotonic() - handle.started > HELLO_TIMEOUT_S:
                    raise WorkerPoolError(f"rollout worker {handle.index} made no rollout within "
                                          f"{HELLO_TIMEOUT_S:.0f} s of starting")
            if time.monotonic() >= deadline:
                return None

    def release(self, delivery: Delivery, env_steps: int) -> None:
        """The learner is done with the delivery's arrays: its slot goes back to its worker."""
        handle = self._handles[delivery.worker]
        handle.held.discard(delivery.slot)
        self._env_steps = max(self._env_steps, env_steps)
        if handle.alive and handle.conn is not None:
            try:
                handle.conn.send(("free", delivery.slot, env_steps))
            except OSError:
                pass                             # dead: found by the next get

    def close(self) -> None:
        for handle in self._handles:
            if handle.conn is not None:
                try:
                    handle.conn.send(("stop",))
                except OSError:
                    pass
        for handle in self._handles:
            if handle.process is not None:
                handle.process.join(timeout=5.0)
                if handle.process.is_alive():
                    handle.process.kill()
                    handle.process.join(timeout=5.0)
            if handle.conn is not None:
                handle.conn.close()
                handle.conn = None
            handle.alive = False
            if handle.slots is not None:
                handle.slots.close()
                handle.slots = None
        if self.server is not None:
            self.server.close()
            self.server = None
        if self._weights is not None:
            self._weights.close()
            self._weights = None


