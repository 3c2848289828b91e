#!/usr/bin/env python3
"""``make lint``: ruff (ruff.toml), mypy (mypy.ini: strict on the packages it lists) and import-linter (the layers and
rules of .importlinter), each run to the end so that one report shows every problem; exit status 1 if any failed.

``make test`` runs it before the suite. Run from the repository root with the venv's Python (the tools come from
requirements.lock); ``tools/lint.py ruff mypy`` runs only those. Why these rules: docs/decisions.md, "Lint".
"""
from __future__ import annotations

import argparse
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
BIN = Path(sys.executable).parent
CHECKS = {
    "ruff": [str(BIN / "ruff"), "check", "."],
    "mypy": [str(BIN / "mypy")],
    "imports": [str(BIN / "lint-imports"), "--no-logo"],
}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="tools/lint.py", description=__doc__.split("\n\n")[0])
    parser.add_argument("checks", nargs="*", metavar="CHECK", help=f"run only these ({', '.join(CHECKS)}; default: all)")
    args = parser.parse_args(argv)
    unknown = [name for name in args.checks if name not in CHECKS]
    if unknown:
        parser.error(f"no check {', '.join(unknown)} (the checks: {', '.join(CHECKS)})")
    failed = []
    for name in args.checks or list(CHECKS):
        started = time.monotonic()
        result = subprocess.run(CHECKS[name], cwd=ROOT, capture_output=True, text=True)
        took = time.monotonic() - started
        if result.returncode != 0:
            failed.append(name)
            print((result.stdout + result.stderr).rstrip())
        print(f"lint: {name} {'failed' if result.returncode else 'passed'} ({took:.0f} s)", flush=True)
    if failed:
        print(f"lint: {', '.join(failed)} failed (ruff.toml, mypy.ini, .importlinter; docs/decisions.md, 'Lint')")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
