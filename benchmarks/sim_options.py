"""Command-line options of ``dynenv-bench sim`` (kept apart so parsing imports no simulator code)."""
from __future__ import annotations

import argparse

SCENARIOS = ("robocup",)
OBSERVATIONS = ("none", "ground_truth", "pettingzoo")
NOISE = ("none",)   # perception presets arrive with the perception model


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--scenario", choices=SCENARIOS, default="robocup")
    parser.add_argument("--players-per-team", type=int, default=2)
    parser.add_argument("--steps", type=int, default=5000, help="motion periods (env steps) to time")
    parser.add_argument("--observation", choices=OBSERVATIONS, default="none",
                        help="none: physics and rules only; ground_truth: plus team-frame observations; "
                             "pettingzoo: the full Parallel API step")
    parser.add_argument("--noise", choices=NOISE, default="none")
    parser.add_argument("--envs", type=int, default=1, help="worlds stepped as one vectorised batch")
    parser.add_argument("--backend", choices=("inprocess", "subprocess"), default="inprocess",
                        help="vectorised backend when --envs > 1")
    parser.add_argument("--cores", type=int, default=1,
                        help="CPU cores this process may use (pinned with sched_setaffinity); 0 = no pinning")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--json", action="store_true", help="print one JSON object instead of a table")
