"""dynenv-bench: speed and size figures of dynenv_ros. Each suite prints its figures; results go in docs/benchmarks.md.

Suites are imported only when chosen, so a suite's memory figures carry nothing of the others (no rclpy, no torch).
"""
from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Sequence

# suite name -> module in this package with ``add_arguments(parser)`` and ``run(args) -> int``
SUITES = {"msgs": "messages", "setup": "setup_cost", "sim": "sim", "vector": "vector", "ros": "ros_graph",
          "policy": "policy", "train": "train", "learner": "learner", "soak": "soak",
          "flood": "flood", "ros-train": "ros_train", "cores": "cores", "auth": "auth", "camera": "camera",
          "live-view": "live_view", "localization": "localization", "weights-flood": "weights_flood"}
# suites whose one run lasts minutes: one run unless --repeat asks for more
LONG_SUITES = {"soak": 1, "flood": 1, "ros-train": 1, "camera": 1, "weights-flood": 1}
# suites that do not repeat their measurement (yet)
RUNS_ONCE = {"ros-train"}


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="dynenv-bench", description=__doc__)
    suites = parser.add_subparsers(dest="suite", required=True, metavar="SUITE",
                                   help=f"one of: {', '.join(SUITES)}")
    modules = {}
    for name, module_name in SUITES.items():
        sub = suites.add_parser(name)
        modules[name] = module_name
        sub.add_argument("--repeat", type=int, default=LONG_SUITES.get(name, 3), help=(
            "not used yet: this suite runs once" if name in RUNS_ONCE else
            "repetitions; the median and range are reported" + (
                " (default 1: one run lasts minutes)" if name in LONG_SUITES else "")))
        if name == "sim":   # its options are cheap to declare without importing the simulator
            from benchmarks.sim_options import add_arguments
            add_arguments(sub)
        if name == "vector":   # numpy only
            from benchmarks.vector import add_arguments as add_vector_arguments
            add_vector_arguments(sub)
        if name == "policy":   # declaring its options imports no torch
            from benchmarks.policy import add_arguments as add_policy_arguments
            add_policy_arguments(sub)
        if name == "train":   # declaring its options imports no torch
            from benchmarks.train import add_arguments as add_train_arguments
            add_train_arguments(sub)
        if name == "learner":
            from benchmarks.learner import add_arguments as add_learner_arguments
            add_learner_arguments(sub)
        if name == "soak":    # declaring its options starts nothing
            from benchmarks.soak import add_arguments as add_soak_arguments
            add_soak_arguments(sub)
        if name == "flood":
            from benchmarks.flood import add_arguments as add_flood_arguments
            add_flood_arguments(sub)
        if name == "cores":   # numpy only, in its worker processes
            from benchmarks.cores import add_arguments as add_cores_arguments
            add_cores_arguments(sub)
        if name == "camera":   # declaring its options starts nothing
            from benchmarks.camera import add_arguments as add_camera_arguments
            add_camera_arguments(sub)
        if name == "weights-flood":   # declaring its options starts nothing
            from benchmarks.weights_flood import add_arguments as add_weights_flood_arguments
            add_weights_flood_arguments(sub)
        if name == "localization":   # declaring its options imports nothing
            from benchmarks.localization import add_arguments as add_localization_arguments
            add_localization_arguments(sub)
        if name == "live-view":   # declaring its options starts nothing
            from benchmarks.live_view import add_arguments as add_live_view_arguments
            add_live_view_arguments(sub)
        if name == "ros-train":
            from benchmarks.ros_train import add_arguments as add_ros_train_arguments
            add_ros_train_arguments(sub)
        if name in ("msgs", "setup", "auth"):
            sub.add_argument("--json", action="store_true", help="print one JSON object instead of a table")
        if name == "ros":
            sub.add_argument("--sim-seconds", type=float, default=60.0, help="sim seconds per stepped game")
            sub.add_argument("--wall-seconds", type=float, default=10.0, help="realtime CPU sampling window")
            sub.add_argument("--json", action="store_true")
    args = parser.parse_args(argv)
    if args.repeat < 1:
        parser.error("--repeat must be at least 1")
    module = importlib.import_module(f"benchmarks.{modules[args.suite]}")
    return module.run(args)


if __name__ == "__main__":
    sys.exit(main())
