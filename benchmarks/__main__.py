"""dynenv-bench: speed and size figures of dynenv_ros. Each suite prints a table; results go in docs/benchmarks.md."""
from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

from benchmarks import messages, setup_cost

SUITES = {"msgs": messages.run, "setup": setup_cost.run}


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="dynenv-bench", description=__doc__)
    parser.add_argument("suite", choices=sorted(SUITES), help="which benchmark to run")
    parser.add_argument("--repeat", type=int, default=3, help="repetitions; the best is reported")
    args = parser.parse_args(argv)
    if args.repeat < 1:
        parser.error("--repeat must be at least 1")
    return SUITES[args.suite](args.repeat)


if __name__ == "__main__":
    sys.exit(main())
