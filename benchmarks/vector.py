"""dynenv-bench vector: the vectorised batch with perception, in this process on one core against worker processes
on every core.

Both batches hold ``--envs`` worlds (2v2, padded observations, realistic perception by default) and step them with
random high-level actions from a pre-drawn pool (the policy costs nothing); the figure is env steps per second
summed over worlds, the whole ``SoccerVectorEnv.step`` included (action checks, perception, packing, the copies
handed back). The in-process batch runs pinned to one core, the subprocess batch with every core this process may
use: one shard of worlds per core, this process stepping the first itself and a worker process each of the others
(``SoccerVectorEnv(parent_steps=True)``, the default; ``--no-parent-steps``: a worker for every shard, this process
only waiting, as before), each worker pinned to its shard's core unless ``--no-pin-workers``.

What the cores themselves allow is timed too: the ``ceiling`` runs one plain in-process batch per core (the worlds
split as among the shards), each in its own process pinned to its core, started together, with no pipe, shared
memory or lock step between them (a chunk lasts as long as the slower of them). ``subprocess / ceiling`` is then
what the subprocess backend keeps of what the machine can give (lost: pipes, copies, each step waiting for the
slower shard); ``ceiling / inprocess`` is how far the cores scale at all (below 2 where two cores slow each other
down: shared caches, hyper-threads, other work on the machine or its host).

On a shared machine the speed drifts by ±10 % within seconds, so the three are timed interleaved in chunks of
``--chunk`` batch steps (in-process, subprocess, ceiling, in-process, …): all three see the same conditions.
``--repeat`` rounds of ``--steps`` batch steps each; every figure is the median and [min, max] over the rounds
(``benchmarks/timing.py``), by wall time and by CPU time — the subprocess batch's CPU time is this process's and its
workers' (``/proc/<pid>/stat``), the ceiling's that of its processes summed, so a rate per CPU second says how much
work a CPU-second buys, whoever else shares the machine.

``--scenario driving`` times ``DrivingVectorEnv`` the same way: ``--envs`` driving worlds of ``--cars`` cars, padded
observations under the ``--perception`` preset (or ``--observation full``), random discrete actions from a pool.
"""
from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import os
import platform
from typing import Any

import numpy as np

from benchmarks.sim_options import NOISE
from benchmarks.timing import ZERO, Clock, Reading, print_table, stat, table_rows

WARMUP_STEPS = 20
ACTION_POOL = 256


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--scenario", choices=("robocup", "driving"), default="robocup")
    parser.add_argument("--cars", type=int, default=2, help="cars per world (--scenario driving, 1..10)")
    parser.add_argument("--perception", choices=("realistic", "dynenv", "none"), default="realistic",
                        help="driving perception preset (--scenario driving, padded)")
    parser.add_argument("--envs", type=int, default=8, help="worlds in each batch")
    parser.add_argument("--players-per-team", type=int, default=2)
    parser.add_argument("--steps", type=int, default=200,
                        help="batch steps timed per round for each of the three (env steps = steps x envs)")
    parser.add_argument("--chunk", type=int, default=10, help="batch steps per interleaved chunk")
    parser.add_argument("--observation", choices=("padded", "full"), default="padded")
    parser.add_argument("--noise", choices=NOISE, default="realistic", help="perception error mode (padded)")
    parser.add_argument("--preset", choices=("realistic", "dynenv"), default="realistic")
    parser.add_argument("--noise-magnitude", type=float, default=1.0, help="0..5")
    parser.add_argument("--workers", type=int, default=0,
                        help="subprocess shards (SoccerVectorEnv(workers=...)); 0 = one per core")
    parser.add_argument("--parent-steps", action=argparse.BooleanOptionalAction, default=True,
                        help="this process steps the first shard itself, worker processes the others "
                             "(SoccerVectorEnv(parent_steps=True), the default); --no-parent-steps: a worker per shard")
    parser.add_argument("--pin-workers", action=argparse.BooleanOptionalAction, default=True,
                        help="pin the worker of shard s to core s (SoccerVectorEnv(pin_workers=True))")
    parser.add_argument("--cores", type=int, default=0,
                        help="cores for the subprocess batch (the first N this process may use); 0 = all of them")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--json", action="store_true", help="print one JSON object instead of a table")


def _env_class(scenario: str) -> Any:
    from dynenv_ros.envs.vector import DrivingVectorEnv, SoccerVectorEnv
    return DrivingVectorEnv if scenario == "driving" else SoccerVectorEnv


def _plain_batch(conn: Any, core: int, envs: int, kwargs: dict[str, Any], batches: np.ndarray, seed: int,
                 scenario: str = "robocup") -> None:
    """One process of the ceiling: pinned to ``core``, an in-process batch of ``envs`` worlds; steps ``n`` batch
    steps whenever it receives ``n`` and answers the seconds they took (0 ends it)."""
    os.sched_setaffinity(0, [core])
    clock = Clock()
    with _env_class(scenario)(envs, backend="inprocess", **kwargs) as env:
        env.reset(seed=seed)
        _span(env, batches[:, :envs], WARMUP_STEPS, 0, clock)
        conn.send(None)
        start = WARMUP_STEPS
        while steps := conn.recv():
            conn.send(_span(env, batches[:, :envs], steps, start, clock))
            start += steps


def _span(env: Any, batches: np.ndarray, steps: int, start: int, clock: Clock) -> Reading:
    """Wall and CPU seconds (by ``clock``) of ``steps`` batch steps."""
    begin = clock.read()
    for k in range(start, start + steps):
        env.step(batches[k % ACTION_POOL])
    return clock.read() - begin


def run(args: Any) -> int:
    if min(args.envs, args.steps, args.chunk) < 1 or not 1 <= args.players_per_team <= 5:
        raise SystemExit("--envs, --steps and --chunk must be at least 1, --players-per-team in 1..5")
    from benchmarks.sim import perception_setting
    from dynenv_ros.soccer.config import SoccerConfig

    allowed = sorted(os.sched_getaffinity(0))
    cores = allowed[:args.cores] if args.cores > 0 else allowed
    one_core = cores[:1]
    rng = np.random.default_rng(args.seed)
    driving = getattr(args, "scenario", "robocup") == "driving"
    VectorEnv = _env_class("driving" if driving else "robocup")
    if driving:
        from dynenv_ros.driving.config import DrivingConfig
        if not 1 <= args.cars <= 10:
            raise SystemExit("--cars must be in 1..10")
        config: Any = DrivingConfig(n_cars=args.cars)
        pool = rng.integers(0, 3, size=(ACTION_POOL, config.n_cars, 2))
        kwargs = dict(config=config, observation=args.observation,
                      perception=args.perception if args.observation == "padded" else None)
    else:
        config = SoccerConfig(players_per_team=args.players_per_team)
        pool = rng.integers([0, 0, 0, 0], [5, 3, 3, 2 * config.motion.head_units + 1],
                            size=(ACTION_POOL, config.n_robots, 4))
        kwargs = dict(config=config, observation=args.observation,
                      perception=perception_setting(args) if args.observation == "padded" else "none")
    batches = np.stack([np.roll(pool, e, axis=0) for e in range(args.envs)], axis=1)
    os.sched_setaffinity(0, cores)            # the forkserver, and so every worker, may use all of these
    workers = args.workers or len(cores)
    subprocess = VectorEnv(args.envs, backend="subprocess", workers=workers, pin_workers=args.pin_workers,
                                 parent_steps=args.parent_steps, **kwargs)
    inprocess = VectorEnv(args.envs, backend="inprocess", **kwargs)
    context = mp.get_context("forkserver")
    plain = []
    names = ("inprocess", "subprocess", "ceiling")
    spans = {name: [ZERO] * args.repeat for name in names}      # per round: wall and CPU seconds
    parent_envs, processes = subprocess._batch.parent_envs, len(subprocess._batch._procs)
    clocks = {"inprocess": Clock(), "subprocess": Clock(pids=[proc.pid for proc in subprocess._batch._procs])}
    try:
        shares = subprocess._batch.sizes
        for w, share in enumerate(shares):
            parent, child = context.Pipe()
            proc = context.Process(target=_plain_batch, daemon=True, args=(
                child, cores[w % len(cores)], share, kwargs, batches, args.seed, "driving" if driving else "robocup"))
            proc.start()
            plain.append((parent, proc))
        for env, pinned in ((inprocess, one_core), (subprocess, cores)):
            os.sched_setaffinity(0, pinned)
            env.reset(seed=args.seed)
            _span(env, batches, WARMUP_STEPS, 0, Clock())
        for conn, _ in plain:
            conn.recv()                       # warmed up
        start = WARMUP_STEPS
        for r in range(args.repeat):
            for done in range(0, args.steps, args.chunk):
                n = min(args.chunk, args.steps - done)
                for name, env, pinned in (("inprocess", inprocess, one_core), ("subprocess", subprocess, cores)):
                    os.sched_setaffinity(0, pinned)
                    spans[name][r] += _span(env, batches, n, start, clocks[name])
                for conn, _ in plain:
                    conn.send(n)
                chunk = [conn.recv() for conn, _ in plain]                 # started together: the slower's wall
                spans["ceiling"][r] += Reading(max(c.wall_s for c in chunk), sum(c.cpu_s for c in chunk))
                start += n
    finally:
        for conn, proc in plain:
            try:
                conn.send(0)
            except OSError:
                pass
            proc.join(timeout=10)
            if proc.is_alive():
                proc.kill()
        inprocess.close()
        subprocess.close()
        os.sched_setaffinity(0, allowed)
    env_steps = args.steps * args.envs
    wall = {name: np.array([span.wall_s for span in spans[name]]) for name in names}
    cpu = {name: np.array([span.cpu_s for span in spans[name]]) for name in names}
    figures = {
        "envs": args.envs, "players_per_team": args.players_per_team, "observation": args.observation,
        "perception": kwargs["perception"], "steps": args.steps, "chunk": args.chunk, "rounds": args.repeat,
        "workers": workers, "parent_steps": args.parent_steps, "parent_envs": parent_envs,
        "worker_processes": processes, "pin_workers": args.pin_workers, "inprocess_cores": len(one_core),
        "subprocess_cores": len(cores),
    }
    for name in names:
        figures[f"{name}_env_steps_per_s"] = stat(env_steps / wall[name])
        figures[f"{name}_env_steps_per_cpu_s"] = stat(env_steps / cpu[name])
    figures.update({          # per round, by wall time: each ratio's median and range over the rounds
        "ratio": stat(wall["inprocess"] / wall["subprocess"], 3),
        "ceiling_over_inprocess": stat(wall["inprocess"] / wall["ceiling"], 3),
        "subprocess_over_ceiling": stat(wall["ceiling"] / wall["subprocess"], 3),
        "python": platform.python_version(),
    })
    what = f"driving {args.cars} cars" if driving else f"{args.players_per_team}v{args.players_per_team}"
    seen = ("ground truth" if args.observation == "full" else
            f"{args.perception if driving else args.preset} perception")
    figures["measures"] = (f"{what}, {args.envs} worlds: the whole batch step, {args.observation} observations "
                           f"({seen}), in-process on 1 core against subprocess on {len(cores)}")
    if driving:
        del figures["players_per_team"]
        figures = {"scenario": "driving", "cars": args.cars, **figures}
    if args.json:
        print(json.dumps(figures))
    else:
        print(f"measures: {figures['measures']}")
        print_table(f"dynenv-bench vector: {args.envs} worlds {what} {args.observation} (median [min–max] of "
                    f"{args.repeat} rounds)", table_rows(figures, ["measures"]))
    return 0
