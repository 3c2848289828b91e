"""The agent's training passes in torch: what a trainer pays per rollout (``dynenv-bench policy --agent``, or
``python -m benchmarks.agent``).

Two figures, on real observations — ``SoccerVectorEnv(--envs)`` (2v2, realistic perception, padded layout at its
default maxima: 40 landmark and 8 object slots) stepped with random actions, every world's robots flattened into one
batch (8 worlds = 32 robots):

* acting: one ``DynEnvAgent.forward`` under ``torch.no_grad()`` for all robots (what a trainer runs per env step);
* training: ``forward_sequence`` over ``--sequence`` consecutive periods of all robots (one robot's episode restarting
  halfway, so the reset path is in it), then ``backward`` of a loss touching the policy logits, the value, the pose
  and the reconstruction outputs.

A run times ``--iterations`` calls after a quarter as many untimed ones and gives their median by wall time and by
CPU time (``time.process_time()``: on a shared machine the time other processes held the core is not counted), and
the fastest call; with ``--repeat`` runs each of those is reported as the median and [min, max] over the runs
(``benchmarks/timing.py``). Pinned to ``--cores`` cores with ``--threads`` torch threads. A model without
``forward_sequence`` (the network before it) is timed calling ``forward`` once per period instead.
"""
from __future__ import annotations

import argparse
import json
import platform
import statistics
import sys
from typing import Any, Callable

from benchmarks.timing import Clock, format_stat, pin_cores, print_table, stat, torch_threads


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The options of this benchmark that ``dynenv-bench policy`` does not already declare (no torch import)."""
    parser.add_argument("--envs", type=int, default=8, help="2v2 worlds whose robots form the batch (--agent)")
    parser.add_argument("--sequence", type=int, default=6, help="periods per forward_sequence (--agent)")
    parser.add_argument("--iterations", type=int, default=20, help="timed calls per figure and run (--agent)")


def _record(envs: int, periods: int, seed: int) -> tuple[list[dict[str, Any]], float]:
    """``periods`` consecutive padded observations of ``envs`` worlds, robots flattened: {key: (E·A, ...)}."""
    import numpy as np

    from dynenv_ros.envs.vector import SoccerVectorEnv

    env = SoccerVectorEnv(envs, backend="inprocess")
    try:
        env.reset(seed=seed)
        rng = np.random.default_rng(seed)
        counts = (5, 3, 3, 2 * env.config.motion.head_units + 1)
        out = []
        for _ in range(periods):
            actions = np.stack([rng.integers(0, n, (envs, env.config.n_robots)) for n in counts], -1)
            observation = env.step(actions).observations
            out.append({key: value.reshape(-1, *value.shape[2:]) for key, value in observation.items()})
        return out, float(env.config.motion.head_max_delta)
    finally:
        env.close()


def inputs(observations: list[dict[str, Any]], head_max: float) -> tuple:
    """(landmarks, objects, previous action, proprioception) with leading (T, B) axes from T flattened
    observations."""
    import torch

    from dynenv_ros.agent.inputs import StreamBatch, side_inputs, streams_from_padded

    steps = [(*streams_from_padded(o), *side_inputs(o, head_max)) for o in observations]

    def stack(index: int) -> Any:
        if isinstance(steps[0][index], StreamBatch):
            return StreamBatch(*(torch.stack([getattr(s[index], name) for s in steps])
                                 for name in ("features", "kind", "mask")))
        return torch.stack([s[index] for s in steps])

    return tuple(stack(i) for i in range(4))


def _loss(step: Any, targets: dict[str, Any]) -> Any:
    """A stand-in for the trainer's loss: every output kind it trains enters."""
    import torch.nn.functional as F

    heads = [("walk", step.walk), ("turn", step.turn), ("kick", step.kick)]
    policy = sum(F.cross_entropy(logits.flatten(0, -2), targets[name].flatten())
                 for name, logits in heads + ([("head", step.head)] if "head" in targets else []))
    if "head" not in targets:           # continuous head turn: [mean, log_std]
        policy = policy + step.head.pow(2).mean()
    return (policy + (step.value - targets["value"]).pow(2).mean() + (step.pose - targets["pose"]).pow(2).mean()
            + step.ball.pow(2).mean() + F.softplus(step.ball_confidence).mean() + step.robots.pow(2).mean()
            + F.softplus(step.robot_confidence).mean())


def _calls(call: Callable[[], Any], iterations: int, warmup: int) -> dict[str, float]:
    """Median ms by wall and by CPU time, and the fastest ms by wall time, of ``iterations`` calls after ``warmup``
    untimed ones."""
    for _ in range(warmup):
        call()
    clock, wall, cpu = Clock(), [], []
    for _ in range(iterations):
        start = clock.read()
        call()
        span = clock.read() - start
        wall.append(1e3 * span.wall_s)
        cpu.append(1e3 * span.cpu_s)
    return {"ms": statistics.median(wall), "cpu_ms": statistics.median(cpu), "fastest_ms": min(wall)}


def run(args: Any) -> int:
    if args.envs < 1 or args.sequence < 1 or args.iterations < 1 or args.threads < 1:
        print("--envs, --sequence, --iterations and --threads must be at least 1", file=sys.stderr)
        return 2
    cores = pin_cores(args.cores)
    import torch

    torch_threads(args.threads)
    from dynenv_ros.agent.network import DynEnvAgent, parameter_count

    observations, head_max = _record(args.envs, args.sequence, args.seed)
    landmarks, objects, previous, proprio = inputs(observations, head_max)
    T, B = previous.shape[:2]
    torch.manual_seed(args.seed)
    model = DynEnvAgent(feature_size=args.feature_size, head_mode=args.head_mode)
    generator = torch.Generator().manual_seed(args.seed)
    head_classes = model.head_head.out_features if args.head_mode == "discrete" else None
    targets = {name: torch.randint(0, n, (T, B), generator=generator)
               for name, n in (("walk", 5), ("turn", 3), ("kick", 3), ("head", head_classes or 1))}
    targets["value"] = torch.randn(T, B, generator=generator)
    targets["pose"] = torch.randn(T, B, 6, generator=generator)
    if head_classes is None:
        del targets["head"]
    resets = torch.zeros(T, B, dtype=torch.bool)
    resets[T // 2, 0] = True
    state = model.initial_state(B)
    sequence = getattr(model, "forward_sequence", None)

    def at(batch: Any, t: int) -> Any:
        return type(batch)(batch.features[t], batch.kind[t], batch.mask[t])

    def act() -> None:
        with torch.no_grad():
            model(at(landmarks, 0), at(objects, 0), previous[0], proprio[0], state)

    def train() -> None:
        if sequence is not None:
            step = sequence(landmarks, objects, previous, proprio, state, resets)
            loss = _loss(step, targets)
        else:      # a model without forward_sequence (the figures before it): one forward per period
            carried, loss = state, 0.0
            for t in range(T):
                if resets[t].any():
                    keep = (~resets[t]).float().unsqueeze(-1)
                    carried = tuple(s * keep for s in carried)
                step = model(at(landmarks, t), at(objects, t), previous[t], proprio[t], carried)
                carried = step.state
                loss = loss + _loss(step, {k: v[t] for k, v in targets.items()}) / T
        model.zero_grad(set_to_none=True)
        loss.backward()

    runs, warmup = [], max(2, args.iterations // 4)
    for _ in range(max(1, getattr(args, "repeat", 1))):
        model.eval()
        acting = _calls(act, args.iterations, warmup)
        model.train()
        training = _calls(train, args.iterations, warmup)
        runs.append({**{f"acting_{k}": v for k, v in acting.items()},
                     **{f"training_{k}": v for k, v in training.items()}})
    timed = {key: stat((run[key] for run in runs), 3) for key in runs[0]}
    valid_landmarks = (~landmarks.mask).sum(-1).float()
    valid_objects = (~objects.mask).sum(-1).float()
    figures = {
        "parameters": parameter_count(model), "feature_size": args.feature_size, "head_mode": args.head_mode,
        "robots": B, "sequence": T, "landmark_slots": landmarks.mask.shape[-1], "object_slots": objects.mask.shape[-1],
        "landmarks_per_frame_mean_max": [round(valid_landmarks.mean().item(), 2), int(valid_landmarks.max())],
        "objects_per_frame_mean_max": [round(valid_objects.mean().item(), 2), int(valid_objects.max())],
        "forward_sequence": sequence is not None, "threads": args.threads, "cores": len(cores),
        "iterations": args.iterations, "warmup": warmup, "repeat": max(1, getattr(args, "repeat", 1)),
        **timed, "torch": torch.__version__, "python": platform.python_version(),
    }
    if args.json:
        print(json.dumps(figures))
    else:
        rows = [(k, str(v)) for k, v in figures.items() if not k.startswith(("acting", "training"))]
        for name, what in (("acting", f"acting forward, {B} robots"),
                           ("training", f"forward_sequence + backward, {T}x{B}")):
            rows.append((what, f"{format_stat(timed[f'{name}_ms'], '{:.2f}')} ms; by CPU time "
                               f"{format_stat(timed[f'{name}_cpu_ms'], '{:.2f}')} ms; fastest call "
                               f"{format_stat(timed[f'{name}_fastest_ms'], '{:.2f}')} ms"))
        print_table(f"dynenv-bench policy --agent: the agent's training passes in torch, a run's median call, "
                    f"median [min–max] of {figures['repeat']} runs", rows)
    return 0


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(description=__doc__)
    add_arguments(parser)
    parser.add_argument("--feature-size", type=int, default=64)
    parser.add_argument("--head-mode", choices=("discrete", "continuous"), default="discrete")
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--cores", type=int, default=1, help="cores to pin to (0 = no pinning)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--repeat", type=int, default=3, help="runs; the median and range are reported")
    parser.add_argument("--json", action="store_true")
    return parser


if __name__ == "__main__":
    sys.exit(run(_parser().parse_args()))
