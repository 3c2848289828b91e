#!/usr/bin/env python3
"""The original DynEnv's soccer step beside ours, timed the same way: env steps per CPU second on one core.

Two parts, both in this file (no code of the original is copied here; it is imported from a checkout of it):

- ``measure``, run with the original's own interpreter (Python 3.8 and its packages, see
  ``tools/original_benchmark.sh``): builds its RoboCup environment — ``nPlayers`` per team, partial observations,
  realistic noise at magnitude 1 (its training default, and our benchmark's) — seeds its global RNGs, steps it with
  uniformly random actions ([walk 0–4, turn 0–2, kick 0–2, head 0–6], like ``dynenv-bench sim``'s pool) from a
  pre-drawn pool, resets it when an episode is over, warms up 50 steps, then times ``--repeat`` runs of ``--steps``
  steps each by ``time.process_time`` (CPU seconds) and ``time.perf_counter`` (wall). Prints one JSON line.
- ``interleave``, run with this project's venv: ``--rounds`` rounds, each one run of ours
  (``python -m benchmarks sim --players-per-team N --observation partial --steps S --repeat R --json`` in
  ``--tree``) and one of the original, back to back, the original first in odd rounds and ours first in even ones
  (a machine that drifts weighs on both alike), every run pinned to ``--core`` by ``taskset``; writes every run's
  JSON as a line of ``--out`` and prints the table: each side's median and range of the runs' medians, and the
  ratio of the medians.
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

WARMUP_STEPS = 50
ACTION_POOL = 256


def _figures(runs_cpu, runs_wall, steps):
    rate = [steps / s for s in runs_cpu]
    wall = [steps / s for s in runs_wall]
    return {"env_steps_per_cpu_s": {"median": statistics.median(rate), "min": min(rate), "max": max(rate),
                                    "runs": rate},
            "env_steps_per_s": {"median": statistics.median(wall), "min": min(wall), "max": max(wall), "runs": wall},
            "cpu_ms_per_env_step": 1000.0 / statistics.median(rate)}


def measure(args: argparse.Namespace) -> int:
    """The original's step, timed (runs under the original's interpreter)."""
    import types

    import numpy as np
    # The package's __init__ imports its training utilities, which import torch at the top and use it only to
    # train and save agents: without torch installed (its wheel with CUDA is gigabytes), an empty module stands in.
    stubbed = []
    try:
        __import__("torch")
    except ImportError:
        sys.modules["torch"] = types.ModuleType("torch")
        stubbed.append("torch")
    sys.path.insert(0, str(Path(args.dynenv).resolve()))
    from DynEnv import NoiseType, ObservationType, RoboCupEnvironment    # the original, from its checkout

    observation = {"partial": ObservationType.PARTIAL, "full": ObservationType.FULL}[args.observation]
    env = RoboCupEnvironment(nPlayers=args.players_per_team, render=False, observationType=observation,
                             noiseType=NoiseType.REALISTIC, noiseMagnitude=args.noise_magnitude)
    env.set_random_seed(args.seed)            # its global numpy and random generators
    env.reset()
    robots = 2 * args.players_per_team
    pool = np.random.RandomState(args.seed).randint([0, 0, 0, 0], [5, 3, 3, 7], size=(ACTION_POOL, robots, 4))
    k = 0

    def run(steps: int) -> None:
        nonlocal k
        for _ in range(steps):
            _, _, finished, _ = env.step(pool[k % ACTION_POOL])
            k += 1
            if finished:
                env.reset()
    run(WARMUP_STEPS)
    cpu, wall = [], []
    for _ in range(args.repeat):
        c0, w0 = time.process_time(), time.perf_counter()
        run(args.steps)
        cpu.append(time.process_time() - c0)
        wall.append(time.perf_counter() - w0)
    print(json.dumps({"side": "original", "players_per_team": args.players_per_team, "observation": args.observation,
                      "noise_magnitude": args.noise_magnitude, "steps": args.steps, "repeat": args.repeat,
                      "python": sys.version.split()[0], "numpy": np.__version__,
                      "pymunk": __import__("pymunk").version, "stubbed": stubbed, **_figures(cpu, wall, args.steps)}))
    return 0


def _last_json(text: str) -> dict:
    for line in reversed(text.splitlines()):
        if line.startswith("{"):
            return json.loads(line)
    raise ValueError("no JSON line in the output")


def interleave(args: argparse.Namespace) -> int:
    """Rounds of ours and the original's, alternating which goes first (runs under this project's venv)."""
    tree = Path(args.tree).resolve()
    pin = ["taskset", "-c", str(args.core)]
    ours = pin + [sys.executable, "-m", "benchmarks", "sim", "--players-per-team", str(args.players_per_team),
                  "--observation", args.observation, "--steps", str(args.steps), "--repeat", str(args.repeat),
                  "--json"]
    original = pin + [args.original_python, str(Path(__file__).resolve()), "measure", "--dynenv", args.dynenv,
                      "--players-per-team", str(args.players_per_team), "--observation", args.observation,
                      "--steps", str(args.original_steps), "--repeat", str(args.repeat)]
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    records = []
    with out.open("w") as log:
        for r in range(1, args.rounds + 1):
            order = [("original", original), ("ours", ours)]
            if r % 2 == 0:
                order.reverse()
            for side, command in order:
                load = os.getloadavg()
                done = subprocess.run(command, cwd=tree if side == "ours" else None, capture_output=True, text=True,
                                      env={**os.environ, "PYTHONPATH": str(tree)} if side == "ours" else None)
                if done.returncode != 0:
                    raise SystemExit(f"round {r} {side} failed ({done.returncode}):\n{done.stderr[-3000:]}")
                figures = _last_json(done.stdout)
                record = {"round": r, "side": side, "command": command, "load_before": load,
                          "time": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()), **figures}
                records.append(record)
                log.write(json.dumps(record) + "\n")
                log.flush()
                print(f"round {r} {side}: {figures['env_steps_per_cpu_s']['median']:.1f} env steps per CPU s",
                      flush=True)
    print(summary(records))
    return 0


def summary(records: list) -> str:
    """Each side's median and [min–max] of its runs' medians (env steps per CPU second), and the ratio."""
    rates = {side: [r["env_steps_per_cpu_s"]["median"] for r in records if r["side"] == side]
             for side in ("ours", "original")}
    lines = ["| side | runs | env steps per CPU second: median [min–max] | CPU ms per step |", "|---|---|---|---|"]
    for side, values in rates.items():
        if values:
            m = statistics.median(values)
            lines.append(f"| {side} | {len(values)} | {m:,.1f} [{min(values):,.1f}–{max(values):,.1f}] | "
                         f"{1000 / m:.3f} |")
    if rates["ours"] and rates["original"]:
        ratio = statistics.median(rates["ours"]) / statistics.median(rates["original"])
        low = min(rates["ours"]) / max(rates["original"])
        high = max(rates["ours"]) / min(rates["original"])
        lines.append(f"\nratio of the medians: {ratio:.1f}x (extremes: {low:.1f}x–{high:.1f}x)")
    return "\n".join(lines)


def main(argv: list | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="part", required=True)
    common = argparse.ArgumentParser(add_help=False)
    common.add_argument("--players-per-team", type=int, default=2)
    common.add_argument("--observation", choices=("partial", "full"), default="partial")
    common.add_argument("--repeat", type=int, default=5)
    common.add_argument("--dynenv", help="a checkout of the original (commit bb65ad3)")
    m = sub.add_parser("measure", parents=[common], help="time the original (its own interpreter)")
    m.add_argument("--steps", type=int, default=200)
    m.add_argument("--seed", type=int, default=0)
    m.add_argument("--noise-magnitude", type=float, default=1.0)
    i = sub.add_parser("interleave", parents=[common], help="ours and the original, round by round")
    i.add_argument("--original-python", help="the original's venv interpreter (Python 3.8)")
    i.add_argument("--tree", default=str(Path(__file__).resolve().parent.parent), help="our checkout")
    i.add_argument("--steps", type=int, default=2000, help="our steps per run")
    i.add_argument("--original-steps", type=int, default=200, help="the original's steps per run")
    i.add_argument("--rounds", type=int, default=3)
    i.add_argument("--core", type=int, default=1)
    i.add_argument("--out", required=True, help="JSON lines, one per run")
    i.add_argument("--summary-only", action="store_true", help="print the table of --out; run nothing")
    args = parser.parse_args(argv)
    if args.part == "measure":
        if not args.dynenv:
            parser.error("measure needs --dynenv")
        return measure(args)
    if args.summary_only:
        print(summary([json.loads(line) for line in Path(args.out).read_text().splitlines() if line.strip()]))
        return 0
    if not args.dynenv or not args.original_python:
        parser.error("interleave needs --dynenv and --original-python (or --summary-only)")
    return interleave(args)


if __name__ == "__main__":
    sys.exit(main())
