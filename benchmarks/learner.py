"""dynenv-bench networks: the learner's forward + backward against the machine's FLOP limit.

- The work: one PPO update of a training preset (default ``async``) on a real rollout of its worlds (collected
  first, not timed), every minibatch's forward, backward, gradient clip and Adam step, on one thread.
- Its FLOPs: counted by ``torch.utils.flop_counter.FlopCounterMode`` over the same update (matrix products, the
  attentions' batched products included; element-wise work, a small share, is not counted), divided by the
  robot-periods learnt from: FLOPs per robot-step, forward + backward.
- The limit: the best rate of a large single-precision matrix product on one thread (``--gemm N``: N x N x N),
  which is what the vector units can sustain; and, as a second reference, products of the shapes the network
  itself multiplies (the embeddings' 19→32→64 on a few thousand rows).
- The fraction: the update's counted FLOPs per CPU second over the limit.

Each figure is the median and [min, max] of ``--repeat`` runs, by CPU time (this process, one thread).
"""
from __future__ import annotations

import argparse
import json
import statistics
import time
from typing import Any

from benchmarks.timing import print_table, stat, table_rows


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--config", default="async", help="training preset whose update is measured")
    parser.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE")
    parser.add_argument("--gemm", type=int, default=1024, help="size of the reference matrix product")
    parser.add_argument("--json", action="store_true")


def _rate(work: Any, flops: float, iterations: int) -> float:
    work()
    started = time.process_time()
    for _ in range(iterations):
        work()
    return flops * iterations / (time.process_time() - started)


def measure(args: Any) -> dict[str, Any]:
    import torch
    from torch.utils.flop_counter import FlopCounterMode

    from dynenv_ros.learning.algo.networks import make_agent
    from dynenv_ros.learning.algo.ppo import update
    from dynenv_ros.learning.config import load_config
    from dynenv_ros.learning.algo.networks import TrainingNetworks
    from dynenv_ros.learning.distributed.rollout_transfer import unflatten
    from dynenv_ros.learning.distributed.rollout_worker import RolloutWorker
    from dynenv_ros.learning.train_cli import preset_path
    from dynenv_ros.learning.algo.ppo import update_settings
    from benchmarks.timing import torch_threads
    torch_threads(1)
    cfg = load_config(preset_path(args.config), list(args.overrides))
    worker = RolloutWorker(cfg, 0, 0, cfg.num_envs)
    worker.adopt(0)
    worker.collect(0)                                   # past the first episode starts
    arrays, _ = worker.collect(0)
    worker.close()
    rollout = unflatten(arrays).as_tensors()
    robot_steps = rollout["actions"].shape[0] * rollout["actions"].shape[1] * (cfg.ppo_epochs if cfg.algorithm ==
                                                                                 "ppo" else 1)
    torch.manual_seed(0)
    networks = TrainingNetworks(make_agent(cfg), cfg.ltp_horizon)
    optimizer = torch.optim.Adam(networks.parameters(), lr=cfg.learning_rate, fused=True)
    settings, generator = update_settings(cfg), torch.Generator().manual_seed(0)
    update(networks, optimizer, rollout, settings, generator)        # warm-up
    with FlopCounterMode(display=False) as counter:
        update(networks, optimizer, rollout, settings, generator)
    flops = counter.get_total_flops()
    runs = []
    for _ in range(args.repeat):
        started, wall = time.process_time(), time.perf_counter()
        update(networks, optimizer, rollout, settings, generator)
        runs.append((time.process_time() - started, time.perf_counter() - wall))
    n = args.gemm
    a, b = torch.randn(n, n), torch.randn(n, n)
    gemm = [_rate(lambda: a @ b, 2.0 * n ** 3, 10) for _ in range(args.repeat)]
    rows, hidden, out = 4096, 32, 64
    x, w1, w2 = torch.randn(rows, 19), torch.randn(hidden, 19), torch.randn(out, hidden)
    shaped = [_rate(lambda: torch.nn.functional.linear(torch.nn.functional.linear(x, w1), w2),
                    2.0 * rows * (19 * hidden + hidden * out), 200) for _ in range(args.repeat)]
    cpu = [c for c, _ in runs]
    achieved = [flops / c for c in cpu]
    limit = statistics.median(gemm)
    return {"config": args.config, "robot_steps_per_update": robot_steps, "flops_per_update": flops,
            "flops_per_robot_step": flops / robot_steps,
            "cpu_seconds_per_update": stat(cpu, 4), "wall_seconds_per_update": stat([w for _, w in runs], 4),
            "robot_steps_per_cpu_second": stat([robot_steps / c for c in cpu]),
            "achieved_gflops": stat([x / 1e9 for x in achieved]),
            "gemm_gflops": stat([x / 1e9 for x in gemm]), "embedding_shaped_gflops": stat([x / 1e9 for x in shaped]),
            "fraction_of_gemm": stat([x / limit for x in achieved], 3)}


def run(args: Any) -> int:
    result = measure(args)
    if args.json:
        print(json.dumps(result, indent=2))
        return 0
    print_table(f"dynenv-bench learner (median [range] of {args.repeat}, CPU time, one thread)", table_rows(result))
    return 0
