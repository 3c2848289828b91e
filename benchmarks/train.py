"""dynenv-bench train: end-to-end training throughput of the in-process trainer.

One env step = one motion period of one world, every learning robot acting and learning. The run is the trainer
itself (``dynenv_ros.learning.trainer.Trainer``) in a temporary run directory: warm-up updates first, then timed
updates; the time is split into the rollout (simulation + acting forwards), the learner's forward + backward and
the optimiser (gradient clipping + Adam step). Peak RSS of this process (workers excluded) is reported too.
"""
from __future__ import annotations

import argparse
import json
import resource
import tempfile
import time
from typing import Any

from benchmarks.timing import print_table


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--config", default="paper_a2c", help="preset name or YAML (as dynenv-train)")
    parser.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE")
    parser.add_argument("--updates", type=int, default=30, help="timed updates")
    parser.add_argument("--warmup", type=int, default=3, help="untimed updates first")
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--json", action="store_true")


def _measure(args: Any) -> dict[str, float]:
    from dynenv_ros.learning.config import load_config
    from dynenv_ros.learning.train_cli import preset_path
    from dynenv_ros.learning.trainer import Trainer
    overrides = list(args.overrides) + [f"device={args.device}", "log_every_updates=1000000",
                                        "checkpoint_every_minutes=1000000"]
    cfg = load_config(preset_path(args.config), overrides)
    with tempfile.TemporaryDirectory() as run_dir:
        trainer = Trainer(cfg, run_dir, progress=False)
        from dynenv_ros.learning.algorithms import update
        per_update = cfg.num_envs * cfg.rollout_length
        split = {"rollout": 0.0, "forward_backward": 0.0, "optimizer": 0.0, "other": 0.0}
        for k in range(args.warmup + args.updates):
            t0 = time.perf_counter()
            trainer.learner.eval()
            rollout = trainer.collector.collect(cfg.rollout_length)
            t1 = time.perf_counter()
            trainer.learner.train()
            stats = update(trainer.learner, trainer.optimizer, rollout.as_tensors(trainer.device),
                           trainer.settings, trainer.generator)
            t2 = time.perf_counter()
            if k >= args.warmup:
                split["rollout"] += t1 - t0
                split["forward_backward"] += stats["seconds_forward_backward"]
                split["optimizer"] += stats["seconds_optimizer"]
                split["other"] += (t2 - t1) - stats["seconds_forward_backward"] - stats["seconds_optimizer"]
        trainer.env.close()
    total = sum(split.values())
    steps = args.updates * per_update
    return {"algorithm": cfg.algorithm, "variant": cfg.variant, "num_envs": cfg.num_envs,
            "players_per_team": cfg.players_per_team, "rollout_length": cfg.rollout_length,
            "robots_learning": cfg.num_envs * len(trainer.collector.learning_robots),
            "env_steps_per_second": steps / total,
            **{f"ms_per_update_{k}": 1000 * v / args.updates for k, v in split.items()},
            "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}


def run(args: Any) -> int:
    results = [_measure(args) for _ in range(args.repeat)]
    best = max(results, key=lambda r: r["env_steps_per_second"])
    if args.json:
        print(json.dumps({"best": best, "runs": results}, indent=2))
    else:
        print_table(f"dynenv-bench train (best of {args.repeat})",
                    [(k, f"{v:.1f}" if isinstance(v, float) else str(v)) for k, v in best.items()])
    return 0
