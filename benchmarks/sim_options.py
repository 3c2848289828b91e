"""Command-line options of ``dynenv-bench sim`` (kept apart so parsing imports no simulator code)."""
from __future__ import annotations

import argparse

SCENARIOS = ("robocup", "driving")
OBSERVATIONS = ("none", "full", "partial", "padded", "image")
NOISE = ("realistic", "random", "none")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--scenario", choices=SCENARIOS, default="robocup")
    parser.add_argument("--players-per-team", type=int, default=2)
    parser.add_argument("--cars", type=int, default=2, help="cars of the driving scenario (1..10)")
    parser.add_argument("--steps", type=int, default=5000, help="motion periods (env steps) to time")
    parser.add_argument("--observation", choices=OBSERVATIONS, default=None,
                        help="none: the world's physics and rules only; full / partial / padded / image: the whole "
                             "PettingZoo step with that observation mode. Default: the step training runs, with "
                             "realistic perception — partial for one world (the original's partial step; padded, "
                             "the layout training packs, adds a few %%), padded for --envs > 1")
    parser.add_argument("--noise", choices=NOISE, default="realistic",
                        help="perception error mode (partial, padded and image observations)")
    parser.add_argument("--preset", choices=("realistic", "dynenv"), default="realistic",
                        help="perception parameter preset for --noise realistic/random")
    parser.add_argument("--perception", choices=("realistic", "dynenv", "none"), default="realistic",
                        help="driving perception preset (--scenario driving --observation partial)")
    parser.add_argument("--noise-magnitude", type=float, default=1.0, help="0..5")
    parser.add_argument("--image-size", default="160x120", help="WIDTHxHEIGHT of camera images (--observation image)")
    parser.add_argument("--envs", type=int, default=1, help="worlds stepped as one vectorised batch")
    parser.add_argument("--backend", choices=("inprocess", "subprocess"), default="inprocess",
                        help="vectorised backend when --envs > 1")
    parser.add_argument("--cores", type=int, default=1,
                        help="CPU cores this process may use (pinned with sched_setaffinity); 0 = no pinning")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--json", action="store_true", help="print one JSON object instead of a table")
