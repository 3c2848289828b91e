"""dynenv-bench train: end-to-end training throughput of the in-process trainer, synchronous or asynchronous.

One env step = one motion period of one world, every learning robot acting and learning. The run is the trainer
itself in a temporary run directory: warm-up updates first, then timed updates.

- ``runner: sync`` presets (``paper_a2c``, ``ppo``, …): the time is split into the rollout (simulation + acting
  forwards), the learner's forward + backward and the optimiser (gradient clipping + Adam step).
- ``runner: async`` presets (``async``): the rollout workers run all along; the learner's time is split into waiting
  for a rollout, forward + backward and the optimiser. Env steps are those the learner learnt from.

Wall time and CPU time are both reported: CPU time of this process and of its worker processes (read from
/proc), so a machine shared with other work shows up as wall time the CPU time does not account for. Each figure
is the median of ``--repeat`` runs, with its range. ``--baseline PRESET`` measures a second preset in the same
invocation, run by run interleaved with the first (so both see the same machine), and reports the ratio of their
medians; for an async preset the baseline is ``ppo`` unless ``--baseline none``.

A soccer ``runner: async`` preset also gets, in each repetition after its training runs, the one-world simulation
rate of ``dynenv-bench sim --observation padded`` (one 2v2 world, realistic perception, pinned to one core:
``sim.one_world_padded``, ``--sim-steps`` periods; 0 skips it), and the ratio of the two rates, repetition by
repetition: the async runner's env steps per second ÷ one world's. The ratio is the figure that travels between
machines: both rates follow the machine's speed.
"""
from __future__ import annotations

import argparse
import json
import math
import resource
import statistics
import tempfile
import time
from typing import Any

from benchmarks.timing import Clock, combine, format_stat, print_table, stat, table_rows



def _learner_split(split: dict[str, float], stats: dict[str, float], update_seconds: float) -> None:
    """Book one update's seconds: forward/backward and optimizer as the update measured them, the rest as other."""
    split["forward_backward"] += stats["seconds_forward_backward"]
    split["optimizer"] += stats["seconds_optimizer"]
    split["other"] += update_seconds - stats["seconds_forward_backward"] - stats["seconds_optimizer"]

def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--config", default="paper_a2c", help="preset name or YAML (as dynenv-train)")
    parser.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE")
    parser.add_argument("--updates", type=int, default=None,
                        help="timed updates (default: 30 for a sync preset, 20 for an async one)")
    parser.add_argument("--warmup", type=int, default=3, help="untimed updates first")
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--baseline", default=None, help="a second preset measured interleaved with --config "
                        "(default: ppo for an async --config, none otherwise; 'none' for none)")
    parser.add_argument("--sim-steps", type=int, default=2000,
                        help="a soccer async --config: periods of the one-world simulation measured in each "
                             "repetition beside it (sim --observation padded, 2v2); 0 = not measured")
    parser.add_argument("--json", action="store_true")


def sim_ratio(train_runs: list[dict[str, Any]], sim_runs: list[dict[str, Any]]) -> dict[str, Any]:
    """The one-world simulation's figures over the repetitions (each repetition's sim run is a ``stat`` of one run)
    and the ratio of the training rate to it, repetition by repetition: ``one_world_sim`` and
    ``ratio_to_one_world_sim``."""
    if len(train_runs) != len(sim_runs):
        raise ValueError(f"{len(train_runs)} training runs against {len(sim_runs)} simulation runs")
    rates = [run["env_steps_per_s"]["median"] for run in sim_runs]
    return {"one_world_sim": {"measures": sim_runs[0]["measures"], "steps": sim_runs[0]["steps"],
                              "env_steps_per_s": stat(rates),
                              "env_steps_per_cpu_s": stat(run["env_steps_per_cpu_s"]["median"] for run in sim_runs)},
            "ratio_to_one_world_sim": stat((run["env_steps_per_s"] / rate for run, rate in zip(train_runs, rates)),
                                           3)}


def sim_lines(result: dict[str, Any], name: str) -> list[str]:
    """The printed lines of ``sim_ratio``'s figures in ``result``."""
    sim = result["one_world_sim"]
    return [f"one-world simulation in the same run ({sim['measures']}; {sim['steps']} periods a repetition): "
            f"{format_stat(sim['env_steps_per_s'])} env steps/s",
            f"{name} / one-world simulation env steps per second: {format_stat(result['ratio_to_one_world_sim'])}"]


def _config(name: str, args: Any):
    from dynenv_ros.learning.config import load_config
    from dynenv_ros.learning.train_cli import preset_path
    overrides = list(args.overrides) + [f"device={args.device}", "log_every_updates=1000000",
                                        "checkpoint_every_minutes=1000000"]
    return load_config(preset_path(name), overrides)


def _measure_sync(cfg: Any, args: Any, updates: int) -> dict[str, Any]:
    from dynenv_ros.learning.algo.loop import learn_from
    from dynenv_ros.learning.trainer import Trainer
    with tempfile.TemporaryDirectory() as run_dir:
        trainer = Trainer(cfg, run_dir, progress=False)
        source = trainer.source
        per_update = cfg.num_envs * cfg.rollout_length
        split = {"rollout": 0.0, "forward_backward": 0.0, "optimizer": 0.0, "other": 0.0}
        workers = _vector_worker_pids(source.env)
        for k in range(args.warmup + updates):
            if k == args.warmup:
                clock = Clock(workers)
                start = clock.read()
            t0 = time.perf_counter()
            experience = source.next(trainer.progress, math.inf)
            t1 = time.perf_counter()
            stats = learn_from(experience, trainer.learn, trainer.progress, source)
            t2 = time.perf_counter()
            if k >= args.warmup:
                split["rollout"] += t1 - t0
                _learner_split(split, stats, t2 - t1)
        span = clock.read() - start
        wall, cpu = span.wall_s, span.cpu_s
        trainer.close()
    steps = updates * per_update
    return {"runner": "sync", "algorithm": cfg.algorithm, "variant": cfg.variant, "num_envs": cfg.num_envs,
            "players_per_team": cfg.players_per_team, "rollout_length": cfg.rollout_length,
            "robots_learning": cfg.num_envs * len(source.collector.learning_robots), "processes": 1 + len(workers),
            "env_steps_per_s": steps / wall, "env_steps_per_cpu_s": steps / cpu, "cpu_s": cpu, "wall_s": wall,
            **{f"ms_per_update_{k}": 1000 * v / updates for k, v in split.items()},
            "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}


def _measure_async(cfg: Any, args: Any, updates: int) -> dict[str, Any]:
    from dynenv_ros.learning.algo.loop import learn_from
    from dynenv_ros.learning.trainer import Trainer
    with tempfile.TemporaryDirectory() as run_dir:
        trainer = Trainer(cfg, run_dir, progress=False, log=lambda line: None)
        source = trainer.source
        try:
            split = {"wait": 0.0, "forward_backward": 0.0, "optimizer": 0.0, "other": 0.0}
            lags: list[float] = []
            steps = 0
            for k in range(args.warmup + updates):
                if k == args.warmup:
                    # the workers' processes and the inference server's (inference: server)
                    workers = source.pool.pids() if hasattr(source.pool, "pids") else []
                    clock = Clock(workers)
                    start = clock.read()
                t0 = time.perf_counter()
                experience = source.next(trainer.progress, math.inf)
                t1 = time.perf_counter()
                stats = learn_from(experience, trainer.learn, trainer.progress, source)
                t2 = time.perf_counter()
                if k >= args.warmup:
                    steps += experience.env_steps
                    lags.append(experience.scalars["async/policy_lag"])
                    split["wait"] += t1 - t0
                    _learner_split(split, stats, t2 - t1)
            span = clock.read() - start
            wall, cpu = span.wall_s, span.cpu_s
            robots = experience.batch["actions"].shape[1]
        finally:
            trainer.close()
    servers = 1 if cfg.inference == "server" and workers else 0
    return {"runner": "async", "algorithm": cfg.algorithm, "variant": cfg.variant, "num_envs": cfg.num_envs,
            "players_per_team": cfg.players_per_team, "rollout_length": cfg.rollout_length,
            "robots_learning": robots, "processes": 1 + len(workers), "workers": len(workers) - servers,
            "inference": cfg.inference,
            "env_steps_per_s": steps / wall, "env_steps_per_cpu_s": steps / cpu, "cpu_s": cpu, "wall_s": wall,
            "policy_lag_mean": statistics.fmean(lags),
            "dropped_rollouts": source.dropped,
            **{f"ms_per_update_{k}": 1000 * v / updates for k, v in split.items()},
            "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}


def _vector_worker_pids(env: Any) -> list[int]:
    batch = getattr(env, "_batch", None)
    return [p.pid for p in getattr(batch, "_procs", [])]


def measure(name: str, args: Any) -> dict[str, Any]:
    cfg = _config(name, args)
    updates = args.updates if args.updates is not None else (20 if cfg.runner == "async" else 30)
    result = (_measure_async if cfg.runner == "async" else _measure_sync)(cfg, args, updates)
    return {"config": name, **result}


def run(args: Any) -> int:
    config_cfg = _config(args.config, args)
    baseline = args.baseline if args.baseline is not None else ("ppo" if config_cfg.runner == "async" else "none")
    names = [args.config] + ([baseline] if baseline != "none" else [])
    with_sim = config_cfg.runner == "async" and config_cfg.scenario == "robocup" and args.sim_steps > 0
    runs: dict[str, list[dict[str, Any]]] = {name: [] for name in names}
    sim_runs: list[dict[str, Any]] = []
    for _ in range(args.repeat):                      # interleaved: each repetition measures every preset once
        for name in names:
            runs[name].append(measure(name, args))
        if with_sim:                                  # and the one-world simulation, after them
            from benchmarks.sim import one_world_padded
            sim_runs.append(one_world_padded(args.sim_steps))
    plain = ("num_envs", "players_per_team", "rollout_length", "robots_learning", "processes", "workers",
             "dropped_rollouts", "inference")
    result: dict[str, Any] = {"repeat": args.repeat,
                              "results": {name: combine(r, plain) for name, r in runs.items()}}
    if len(names) == 2:
        per_run = [a["env_steps_per_s"] / b["env_steps_per_s"] for a, b in zip(runs[names[0]], runs[names[1]])]
        result["ratio_env_steps_per_s"] = stat(per_run, 3)
    if with_sim:
        result.update(sim_ratio(runs[args.config], sim_runs))
    if args.json:
        print(json.dumps(result, indent=2))
        return 0
    for name in names:
        print_table(f"dynenv-bench train --config {name} (median [range] of {args.repeat}; wall and CPU time)",
                    table_rows(result["results"][name]))
    if len(names) == 2:
        print(f"{names[0]} / {names[1]} env steps per second: {format_stat(result['ratio_env_steps_per_s'])}")
    if with_sim:
        print("\n".join(sim_lines(result, args.config)))
    return 0
