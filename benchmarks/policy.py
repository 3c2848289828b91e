"""dynenv-bench policy: what one decision of the agent costs a robot process, torch against onnxruntime.

One decision = the detections of one motion period for every robot the process serves → padded tensors (collate,
timed on its own) → one batched forward pass with the recurrent state fed back. The detections are real (a
``robocup_v0`` game with sampled actions, recorded before timing), the model is the default-sized agent with seeded
random weights (speed does not depend on training). The process is pinned to ``--cores`` cores and both runtimes
use ``--threads`` threads, since on a robot the policy shares the CPU with everything else. Each case runs
``--repeat`` times; every figure (a run's median and p95 per decision, by wall time; its median total by CPU time;
decisions per wall and per CPU second) is reported as the median and [min, max] over the runs
(``benchmarks/timing.py``).

``--agent`` times the training side instead (``benchmarks/agent.py``): the torch model's acting forward and
``forward_sequence`` + backward for a batch of worlds' robots.
"""
from __future__ import annotations

import argparse
import json
import platform
import statistics
import sys
import tempfile
import time
from pathlib import Path
from typing import Any, Callable

from benchmarks.timing import Run, format_stat, pin_cores, print_table, summarise, torch_threads


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Declared without importing torch, so parsing stays cheap."""
    parser.add_argument("--robots", default="4,10", help="comma-separated batch sizes (robots per decision)")
    parser.add_argument("--decisions", type=int, default=300, help="timed decisions per case (at least 200)")
    parser.add_argument("--warmup", type=int, default=50, help="untimed decisions before each case")
    parser.add_argument("--feature-size", type=int, default=64)
    parser.add_argument("--head-mode", choices=("discrete", "continuous"), default="discrete")
    parser.add_argument("--max-landmarks", type=int, default=48)
    parser.add_argument("--max-objects", type=int, default=12)
    parser.add_argument("--periods", type=int, default=20, help="recorded motion periods cycled through")
    parser.add_argument("--threads", type=int, default=1, help="intra-op threads of torch and onnxruntime")
    parser.add_argument("--cores", type=int, default=1,
                        help="CPU cores this process may use (pinned with sched_setaffinity); 0 = no pinning")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--json", action="store_true", help="print one JSON object instead of a table")
    parser.add_argument("--agent", action="store_true",
                        help="instead: the agent's passes in torch as a trainer runs them (acting forward of all "
                             "robots of --envs worlds, forward_sequence + backward over --sequence periods; "
                             "benchmarks/agent.py)")
    from benchmarks.agent import add_arguments as add_agent_arguments
    add_agent_arguments(parser)


def _record(robots: int, periods: int, seed: int) -> list[tuple[list, Any, Any]]:
    """``periods`` motion periods of a game with ``robots`` players: (detections per robot, encoded previous
    action, proprioception)."""
    import numpy as np
    import torch

    from dynenv_ros.envs.robocup_v0 import parallel_env
    from dynenv_ros.agent.inputs import encode_previous_action, self_state

    per_team = (robots + 1) // 2
    env = parallel_env(players_per_team=per_team, perception={"preset": "realistic", "noise_magnitude": 1.0})
    env.reset(seed=seed)
    agents = env.possible_agents[:robots]
    space = env.action_space(agents[0])
    units = (int(space.nvec[3]) - 1) // 2
    for index, agent in enumerate(env.possible_agents):
        env.action_space(agent).seed(seed + index)
    out = []
    for _ in range(periods):
        actions = {a: env.action_space(a).sample() for a in env.agents}
        obs, *_ = env.step(actions)
        a = torch.tensor(np.stack([actions[agent] for agent in agents]))
        # the encoding only divides the head turn by head_max, so head units over units give the same [-1, 1]
        previous = encode_previous_action(a[:, 0], a[:, 1], a[:, 2], a[:, 3] - units, float(units))
        proprio = self_state(np.stack([obs[agent]["proprioception"][-1] for agent in agents]),
                             np.stack([obs[agent]["game"] for agent in agents]))
        out.append(([obs[agent]["detections"] for agent in agents], previous, proprio))
    return out


def _percentile(values: list[float], q: float) -> float:
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, round(q * (len(ordered) - 1)))]


def _time_case(policy: Callable, collate: Callable, periods: list, decisions: int, warmup: int) -> Run:
    """One run of ``decisions`` decisions: their wall and CPU seconds, and as extra figures the median and p95 in ms
    of collate, inference and their sum (wall time) and the median total by CPU time."""
    state = policy.initial_state(len(periods[0][0]))
    collate_ms, infer_ms, total_ms, cpu_ms = [], [], [], []
    for i in range(warmup + decisions):
        detections, previous, proprio = periods[i % len(periods)]
        cpu = time.process_time()
        start = time.perf_counter()
        landmarks, objects = collate(detections)
        middle = time.perf_counter()
        step = policy(landmarks, objects, previous, proprio, state)
        end = time.perf_counter()
        cpu = time.process_time() - cpu
        state = step.state
        if i >= warmup:
            collate_ms.append(1e3 * (middle - start))
            infer_ms.append(1e3 * (end - middle))
            total_ms.append(1e3 * (end - start))
            cpu_ms.append(1e3 * cpu)
    figures = {}
    for name, values in (("collate", collate_ms), ("inference", infer_ms), ("total", total_ms)):
        figures[f"{name}_median_ms"] = statistics.median(values)
        figures[f"{name}_p95_ms"] = _percentile(values, 0.95)
    figures["total_cpu_median_ms"] = statistics.median(cpu_ms)
    return Run(decisions, sum(total_ms) / 1e3, sum(cpu_ms) / 1e3, figures)


def run(args: Any) -> int:
    if getattr(args, "agent", False):
        from benchmarks.agent import run as run_agent
        return run_agent(args)
    try:
        robot_counts = [int(text) for text in str(args.robots).split(",") if text.strip()]
    except ValueError:
        print("--robots must be comma-separated integers", file=sys.stderr)
        return 2
    if not robot_counts or not all(1 <= n <= 10 for n in robot_counts):
        print("--robots must be in 1..10", file=sys.stderr)
        return 2
    if args.decisions < 200 or args.warmup < 0 or args.periods < 1 or args.threads < 1:
        print("--decisions must be at least 200, --periods and --threads at least 1", file=sys.stderr)
        return 2
    cores = pin_cores(args.cores)
    import torch

    torch_threads(args.threads)
    from dynenv_ros.agent.export import OnnxPolicy, TorchPolicy, export_onnx
    from dynenv_ros.agent.inputs import collate
    from dynenv_ros.agent.network import DynEnvAgent, parameter_count

    torch.manual_seed(args.seed)
    model = DynEnvAgent(feature_size=args.feature_size, head_mode=args.head_mode).eval()

    def collate_fixed(detections: list) -> tuple:
        return collate(detections, max_landmarks=args.max_landmarks, max_objects=args.max_objects)

    cases = []
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "policy.onnx"
        export_onnx(model, path, max_landmarks=args.max_landmarks, max_objects=args.max_objects)
        size_kb = path.stat().st_size / 1024.0
        runtimes = {"torch": TorchPolicy(model), "onnxruntime": OnnxPolicy(path, threads=args.threads)}
        for robots in robot_counts:
            periods = _record(robots, args.periods, args.seed)
            for name, policy in runtimes.items():
                runs = [_time_case(policy, collate_fixed, periods, args.decisions, args.warmup)
                        for _ in range(max(1, getattr(args, "repeat", 1)))]
                cases.append({"robots": robots, "runtime": name, **summarise(runs, "decisions", digits=4)})
    import onnxruntime

    figures = {
        "parameters": parameter_count(model), "feature_size": args.feature_size, "head_mode": args.head_mode,
        "max_landmarks": args.max_landmarks, "max_objects": args.max_objects, "onnx_kb": round(size_kb, 1),
        "decisions": args.decisions, "warmup": args.warmup, "repeat": max(1, getattr(args, "repeat", 1)),
        "threads": args.threads, "cores": len(cores),
        "torch": torch.__version__, "onnxruntime": onnxruntime.__version__, "python": platform.python_version(),
        "cases": cases,
    }
    if args.json:
        print(json.dumps(figures))
    else:
        rows = [(k, str(v)) for k, v in figures.items() if k != "cases"]
        ms = "{:.3f}"
        for case in cases:
            rows.append((f"{case['robots']:>2} robots {case['runtime']:<11}",
                         f"collate {format_stat(case['collate_median_ms'], ms)} (p95 "
                         f"{case['collate_p95_ms']['median']:.3f})  inference "
                         f"{format_stat(case['inference_median_ms'], ms)} (p95 "
                         f"{case['inference_p95_ms']['median']:.3f})  total {format_stat(case['total_median_ms'], ms)}"
                         f" (p95 {case['total_p95_ms']['median']:.3f}) ms; CPU "
                         f"{format_stat(case['total_cpu_median_ms'], ms)} ms"))
        print_table(f"dynenv-bench policy: per-decision latency in ms, a run's median (p95), median [min–max] of "
                    f"{figures['repeat']} runs", rows)
    return 0


if __name__ == "__main__":
    _parser = argparse.ArgumentParser(description=__doc__)
    add_arguments(_parser)
    _parser.add_argument("--repeat", type=int, default=1,
                         help="runs per case; the median and range are reported")
    sys.exit(run(_parser.parse_args()))
