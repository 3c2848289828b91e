#!/usr/bin/env python3
"""Two commits' speed, measured A/B in one run (issue 40's done-when: ``dynenv-bench sim``, ``train --config async``
and ``policy`` stay within their spread of the commit before the restructuring, ``3cd871e``).

    .venv/bin/python tools/ab_benchmark.py --base 3cd871e --head HEAD --rounds 3 --out runs/ab/issue40
    .venv/bin/python tools/ab_benchmark.py --summary-only --out runs/ab/issue40      # the table again, from the file

Each commit gets a detached git worktree under ``--worktrees`` (``<dir>/<first 12 hex digits>``, reused when it is
already there, clean and at that commit), and every benchmark runs that tree's code, as ``dynenv-bench`` would
(setup.py maps it to ``benchmarks.__main__:main``): ``cd TREE && PYTHONPATH=TREE PYTHON -m benchmarks SUITE ARGS``,
PYTHON being this tool's interpreter (the project's venv) unless ``--python`` says otherwise. PYTHONPATH puts the
tree before the venv's editable install of the main checkout; before anything is timed each tree's imports are
checked to come from it and its packages are byte-compiled. Commits are measured as committed: uncommitted changes
of the checkout are not in the trees.

The suites and their options (the same for both commits: ``3cd871e`` and the restructured code accept the same
options of these three suites, so nothing had to be left out):

- ``sim``: ``sim --players-per-team 2 --observation partial --steps 2000 --repeat 3 --cores 1 --json``, the step
  training runs for one world (realistic perception), pinned to one core; figures ``env_steps_per_s`` and
  ``env_steps_per_cpu_s`` (the suite's median of its 3 repetitions).
- ``train``: ``train --config async --baseline none --updates 15 --warmup 3 --repeat 1 --json``, the asynchronous
  runner (one worker process, the learner on the other core); figures ``env_steps_per_s`` and
  ``env_steps_per_cpu_s`` (learnt env steps; learner and worker CPU time).
- ``policy``: ``policy --robots 10 --decisions 300 --warmup 50 --repeat 3 --threads 1 --cores 1 --json``, a
  10-robot decision with torch and with onnxruntime, one thread on one core; figures ``decisions_per_s`` and
  ``decisions_per_cpu_s`` of each runtime (the suite's median of its 3 repetitions).

``--sim-steps``, ``--train-updates`` and ``--policy-decisions`` change those lengths (a smoke run: ``--rounds 1
--suites sim --sim-steps 50``: 12 s on the busy 2-core machine, one tree checked out and one reused). One round of
the three suites, both commits, should take about 2.5 minutes on the idle machine (sim about 15 s a run, train about
35 s with its 15 s of start-up, policy about 25 s: estimated from docs/benchmarks.md's figures, not measured yet).

Warm-up: before round 1 each suite runs once in each tree at its smallest (sim 10 steps, train one update of 2
worlds, policy 200 decisions; about 50 s in all by the doc test's figures), kept in raw/ but not in the table: numba
compiles the perception kernels into a fresh tree's __pycache__ on their first call, which a reused tree has already
done, and a suite that fails stops the run there, before minutes of measuring.

Interleaving: round r runs every suite on both commits back to back, the base first in odd rounds and the head
first in even ones, so a machine that drifts (warming, another job starting) weighs on both sides alike.

Every run is a line of ``--out``/runs.jsonl (side, ref, commit, suite, round, its position in the pair, the command,
start time, wall seconds, the 1/5/15-minute load average before and after, exit status, the figures, or the error),
and its whole output is kept in ``--out``/raw/. An existing runs.jsonl is never appended to: a new measurement takes
a new ``--out``. At the end the table is printed and written to ``--out``/summary.md.

The table, per suite and figure: the base's median and range (min–max over the rounds), the head's, the ratio of the
medians head / base, and a verdict. Every figure is a rate (per wall or CPU second): higher is faster.

The verdict rule: **within spread** when the head's median lies inside the base's [min, max] or the two ranges
[min, max] overlap (the first implies the second; both are stated because either is what a reader checks first);
otherwise **head faster (outside spread)** or **head slower (outside spread)**. A side with fewer than 2 runs has
no spread: the verdict then says so instead of judging.
"""
from __future__ import annotations

import argparse
import datetime
import json
import os
import statistics
import subprocess
import sys
import time
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
SIDES = ("base", "head")
RUNS_FILE = "runs.jsonl"
RAW_DIR = "raw"
SUMMARY_FILE = "summary.md"


# ---------------------------------------------------------------------------------------------- the suites' figures
def median_of(value: Any, where: str) -> float:
    """A figure as one number: a plain number, or a repeated figure's median (benchmarks/timing.py's ``stat``)."""
    if isinstance(value, dict) and "median" in value:
        value = value["median"]
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ValueError(f"{where}: expected a number or a {{'median': …}} figure, got {value!r}")
    return float(value)


def last_json_object(text: str) -> dict[str, Any]:
    """The last JSON object printed in ``text`` that starts a line (``--json`` output: one line for sim and policy,
    indented over many for train; anything printed before it is skipped)."""
    decoder = json.JSONDecoder()
    starts = [i for i in range(len(text)) if text[i] == "{" and (i == 0 or text[i - 1] == "\n")]
    for start in reversed(starts):
        try:
            value, _ = decoder.raw_decode(text, start)
        except json.JSONDecodeError:
            continue
        if isinstance(value, dict):
            return value
    raise ValueError("no JSON object in the output (the suite's --json line is missing)")


def _field(obj: Mapping[str, Any], key: str, where: str) -> Any:
    if key not in obj:
        raise ValueError(f"{where}: no {key!r} in the suite's JSON (keys: {', '.join(sorted(obj)) or 'none'})")
    return obj[key]


def sim_figures(obj: Mapping[str, Any]) -> dict[str, float]:
    """``dynenv-bench sim --json``: one object, the rates as repeated figures."""
    return {name: median_of(_field(obj, name, "sim"), f"sim {name}")
            for name in ("env_steps_per_s", "env_steps_per_cpu_s")}


def train_figures(obj: Mapping[str, Any], config: str = "async") -> dict[str, float]:
    """``dynenv-bench train --json``: ``results`` per preset; the figures of ``config``'s."""
    results = _field(obj, "results", "train")
    preset = _field(results, config, "train results")
    return {name: median_of(_field(preset, name, f"train {config}"), f"train {config} {name}")
            for name in ("env_steps_per_s", "env_steps_per_cpu_s")}


def policy_figures(obj: Mapping[str, Any]) -> dict[str, float]:
    """``dynenv-bench policy --json``: one case per (robots, runtime), each with its decision rates."""
    cases = _field(obj, "cases", "policy")
    if not isinstance(cases, list) or not cases:
        raise ValueError(f"policy: 'cases' should be a non-empty list, got {cases!r}")
    figures = {}
    for case in cases:
        robots, runtime = _field(case, "robots", "policy case"), _field(case, "runtime", "policy case")
        for name in ("decisions_per_s", "decisions_per_cpu_s"):
            figures[f"{runtime}, {robots} robots: {name}"] = median_of(
                _field(case, name, f"policy {runtime} {robots} robots"), f"policy {runtime} {robots} robots {name}")
    return figures


def learner_figures(obj: Mapping[str, Any]) -> dict[str, float]:
    """``dynenv-bench learner --json``: the update's rate by CPU time and its fraction of the FLOP limit."""
    return {name: median_of(_field(obj, name, "learner"), f"learner {name}")
            for name in ("robot_steps_per_cpu_second", "fraction_of_gemm")}


@dataclass(frozen=True)
class Suite:
    name: str
    arguments: Callable[[argparse.Namespace], list[str]]    # after `python -m benchmarks`
    figures: Callable[[Mapping[str, Any]], dict[str, float]]
    warmup: list[str]      # the same code paths at their smallest, run once per tree before round 1, not recorded


SUITES: dict[str, Suite] = {
    "sim": Suite("sim", lambda a: ["sim", "--players-per-team", "2", "--observation", "partial", "--steps",
                                   str(a.sim_steps), "--repeat", "3", "--cores", "1", "--json"], sim_figures,
                 ["sim", "--players-per-team", "2", "--observation", "partial", "--steps", "10", "--repeat", "1",
                  "--cores", "1", "--json"]),
    "train": Suite("train", lambda a: ["train", "--config", "async", "--baseline", "none", "--updates",
                                       str(a.train_updates), "--warmup", "3", "--repeat", "1", "--json"],
                   train_figures,
                   ["train", "--config", "async", "--baseline", "none", "--updates", "1", "--warmup", "0", "--repeat",
                    "1", "--set", "num_envs=2", "--set", "workers=1", "--json"]),
    "policy": Suite("policy", lambda a: ["policy", "--robots", "10", "--decisions", str(a.policy_decisions),
                                         "--warmup", "50", "--repeat", "3", "--threads", "1", "--cores", "1",
                                         "--json"], policy_figures,
                    ["policy", "--robots", "10", "--decisions", "200", "--warmup", "0", "--repeat", "1", "--threads",
                     "1", "--cores", "1", "--json"]),
    # not in the default set (issue 42's learner changes: --suites learner): one PPO update of the async preset
    "learner": Suite("learner", lambda a: ["learner", "--repeat", "3", "--json"], learner_figures,
                     ["learner", "--repeat", "1", "--set", "num_envs=4", "--json"]),
}
DEFAULT_SUITES = ("sim", "train", "policy")


# ------------------------------------------------------------------------------------------------ spread, verdict
@dataclass(frozen=True)
class Spread:
    median: float
    low: float
    high: float
    runs: int


def spread(values: Iterable[float]) -> Spread:
    values = list(values)
    if not values:
        raise ValueError("spread of no runs")
    return Spread(statistics.median(values), min(values), max(values), len(values))


def verdict(base: Spread, head: Spread) -> str:
    """The rule of the module docstring."""
    if base.runs < 2 or head.runs < 2:
        return f"no spread ({min(base.runs, head.runs)} run): not judged"
    inside = base.low <= head.median <= base.high
    overlap = head.low <= base.high and base.low <= head.high
    if inside or overlap:
        return "within spread"
    return "head faster (outside spread)" if head.median > base.high else "head slower (outside spread)"


def _number(value: float) -> str:
    return f"{value:,.0f}" if abs(value) >= 100 else f"{value:.2f}" if abs(value) >= 1 else f"{value:.4f}"


def _cell(s: Spread) -> str:
    return f"{_number(s.median)} [{_number(s.low)}–{_number(s.high)}]"


def summary_rows(records: list[dict[str, Any]]) -> list[tuple[str, str, Spread | None, Spread | None, str]]:
    """(suite, figure, base spread, head spread, verdict) in the suites' order, figures in the order first seen."""
    values: dict[tuple[str, str], dict[str, list[float]]] = {}
    for record in records:
        for name, value in (record.get("figures") or {}).items():
            values.setdefault((record["suite"], name), {side: [] for side in SIDES})[record["side"]].append(value)
    order = list(SUITES)
    keys = sorted(values, key=lambda k: order.index(k[0]) if k[0] in order else len(order))
    rows = []
    for suite, name in keys:
        sides = values[(suite, name)]
        base = spread(sides["base"]) if sides["base"] else None
        head = spread(sides["head"]) if sides["head"] else None
        judged = verdict(base, head) if base and head else f"only the {'base' if base else 'head'} ran: not judged"
        rows.append((suite, name, base, head, judged))
    return rows


def markdown_table(records: list[dict[str, Any]]) -> str:
    """The report: which commits, rounds, load averages, the table, and the runs that failed."""
    if not records:
        return "no runs recorded\n"
    commits = {side: next(((r["ref"], r["commit"]) for r in records if r["side"] == side), None) for side in SIDES}
    rounds = sorted({r["round"] for r in records})
    loads = [r["load_before"][0] for r in records if r.get("load_before")]
    lines = [" · ".join(f"{side} `{c[0]}` ({c[1][:12]})" if c else f"{side}: no runs"
                        for side, c in commits.items()) + f" · {len(rounds)} round(s)"]
    if loads:
        lines.append(f"load average (1 min) before each run: {min(loads):.2f}–{max(loads):.2f}")
    lines += ["", "| suite | figure | base: median [min–max] | head: median [min–max] | head / base "
              "| runs (base, head) | verdict |", "|---|---|---|---|---|---|---|"]
    for suite, name, base, head, judged in summary_rows(records):
        ratio = f"{head.median / base.median:.3f}" if base and head and base.median else "–"
        lines.append(f"| {suite} | {name} | {_cell(base) if base else '–'} | {_cell(head) if head else '–'} | "
                     f"{ratio} | {base.runs if base else 0}, {head.runs if head else 0} | {judged} |")
    failed = [r for r in records if r.get("error")]
    if failed:
        lines += ["", f"{len(failed)} run(s) failed (not in the table):"]
        lines += [f"- round {r['round']} {r['suite']} {r['side']} ({r['commit'][:12]}): {r['error']}" for r in failed]
    return "\n".join(lines) + "\n"


def read_records(path: Path) -> list[dict[str, Any]]:
    if not path.is_file():
        raise SystemExit(f"no {path}: nothing measured there yet (run without --summary-only first)")
    records = []
    for number, line in enumerate(path.read_text().splitlines(), 1):
        if not line.strip():
            continue
        try:
            record = json.loads(line)
        except json.JSONDecodeError as error:
            raise SystemExit(f"{path}:{number}: not a JSON line ({error})") from None
        missing = {"side", "ref", "commit", "suite", "round"} - set(record)
        if missing or record["side"] not in SIDES:
            raise SystemExit(f"{path}:{number}: not a run record (missing {', '.join(sorted(missing)) or 'a side'})")
        records.append(record)
    return records


# ----------------------------------------------------------------------------------------------- trees and runs
def git(cwd: Path, *args: str) -> str:
    done = subprocess.run(["git", *args], cwd=cwd, capture_output=True, text=True)
    if done.returncode != 0:
        raise SystemExit(f"git {' '.join(args)} (in {cwd}) failed: {(done.stderr or done.stdout).strip()}")
    return done.stdout.strip()


def resolve(ref: str) -> str:
    done = subprocess.run(["git", "rev-parse", "--verify", "--quiet", f"{ref}^{{commit}}"], cwd=ROOT,
                          capture_output=True, text=True)
    if done.returncode != 0:
        raise SystemExit(f"{ref!r} is not a commit of {ROOT}")
    return done.stdout.strip()


def worktree(trees: Path, commit: str) -> Path:
    """The detached worktree of ``commit`` under ``trees``: made, or reused if it is one, at that commit, clean."""
    tree = trees / commit[:12]
    if tree.exists():
        top = subprocess.run(["git", "rev-parse", "--show-toplevel"], cwd=tree, capture_output=True, text=True)
        if top.returncode != 0 or Path(top.stdout.strip()).resolve() != tree.resolve():
            raise SystemExit(f"{tree} exists but is not a git worktree: remove it or choose another --worktrees")
        at = git(tree, "rev-parse", "HEAD")
        if at != commit:
            raise SystemExit(f"{tree} is at {at[:12]}, not {commit[:12]}: `git worktree remove {tree}` it or choose "
                             "another --worktrees")
        changed = git(tree, "status", "--porcelain", "--untracked-files=no")
        if changed:
            raise SystemExit(f"{tree} has changed files, so it is not {commit[:12]} as committed:\n{changed}")
        return tree
    trees.mkdir(parents=True, exist_ok=True)
    git(ROOT, "worktree", "add", "--detach", str(tree), commit)
    return tree


def tree_environment(tree: Path) -> dict[str, str]:
    return {**os.environ, "PYTHONPATH": str(tree)}


def prepare(python: str, tree: Path) -> None:
    """The tree's benchmarks and dynenv_ros are what its runs import (not the venv's editable install), and its
    packages are byte-compiled, so that a fresh tree's first run does not pay for it in its wall seconds."""
    packages = [str(tree / name) for name in ("benchmarks", "dynenv_ros", "policy_node") if (tree / name).is_dir()]
    subprocess.run([python, "-m", "compileall", "-q", *packages], cwd=tree, env=tree_environment(tree),
                   capture_output=True)
    probe = "import benchmarks, dynenv_ros; print(benchmarks.__file__); print(dynenv_ros.__file__)"
    done = subprocess.run([python, "-c", probe], cwd=tree, env=tree_environment(tree), capture_output=True, text=True)
    if done.returncode != 0:
        raise SystemExit(f"{python} cannot import the benchmarks from {tree}:\n{done.stderr.strip()}")
    foreign = [path for path in done.stdout.split() if not Path(path).resolve().is_relative_to(tree.resolve())]
    if foreign:
        raise SystemExit(f"{python} in {tree} imports {', '.join(foreign)}: not the tree's code")


def run_one(python: str, tree: Path, suite: Suite, args: argparse.Namespace, raw: Path,
            arguments: list[str] | None = None) -> dict[str, Any]:
    """One benchmark run in ``tree`` (``arguments``: instead of the suite's measured ones): its command, time,
    load, exit status and figures (or the error)."""
    command = [python, "-m", "benchmarks", *(suite.arguments(args) if arguments is None else arguments)]
    started = datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")
    load_before = os.getloadavg()
    clock = time.monotonic()
    record: dict[str, Any] = {"command": command, "started_utc": started}
    try:
        done = subprocess.run(command, cwd=tree, env=tree_environment(tree), capture_output=True, text=True,
                              timeout=args.timeout)
        stdout, stderr, code = done.stdout, done.stderr, done.returncode
    except subprocess.TimeoutExpired as expired:
        stdout, stderr, code = _text(expired.stdout), _text(expired.stderr), None
    record.update(wall_s=round(time.monotonic() - clock, 2), load_before=[round(v, 2) for v in load_before],
                  load_after=[round(v, 2) for v in os.getloadavg()], returncode=code)
    raw.write_text(f"$ cd {tree} && PYTHONPATH={tree} {' '.join(command)}\n{stdout}\n--- stderr ---\n{stderr}")
    if code is None:
        record["error"] = f"timed out after {args.timeout:g} s"
    elif code != 0:
        tail = stderr.strip().splitlines()[-1:] or ["no stderr"]
        record["error"] = f"exit status {code}: {tail[0]}"
    else:
        try:
            record["figures"] = suite.figures(last_json_object(stdout))
        except ValueError as error:
            record["error"] = str(error)
    return record


def _text(value: bytes | str | None) -> str:
    return value.decode(errors="replace") if isinstance(value, bytes) else value or ""


def warm_up(args: argparse.Namespace, trees: dict[str, Path], commits: dict[str, str], out: Path) -> None:
    """Each suite once in each tree, at its smallest, before anything is timed: numba compiles the perception
    kernels into a fresh tree's __pycache__ on their first call (a reused tree has them), and a suite that fails
    stops the run here rather than after minutes of measuring."""
    warmed: set[Path] = set()
    for side, tree in trees.items():
        if tree in warmed:          # an A/A run: one tree
            continue
        warmed.add(tree)
        for name in args.suites:
            raw = out / RAW_DIR / f"warmup_{name}_{side}.txt"
            record = run_one(args.python, tree, SUITES[name], args, raw, SUITES[name].warmup)
            print(f"warm-up {name} {side}: {record.get('error') or 'ok'} ({record['wall_s']:.0f} s)", flush=True)
            if record.get("error"):
                raise SystemExit(f"the warm-up run of {name} at {side} {commits[side][:12]} failed, nothing was "
                                 f"measured: {record['error']} (its output: {raw})")


def measure(args: argparse.Namespace, out: Path) -> list[dict[str, Any]]:
    refs = {"base": args.base, "head": args.head}
    commits = {side: resolve(ref) for side, ref in refs.items()}
    trees: dict[str, Path] = {}
    for side, commit in commits.items():
        same = side == "head" and commit == commits["base"]     # an A/A run: the base's tree twice
        trees[side] = trees["base"] if same else worktree(args.worktrees, commit)
        prepare(args.python, trees[side])
        print(f"{side}: {refs[side]} = {commit[:12]} in {trees[side]}", flush=True)
    (out / RAW_DIR).mkdir(parents=True, exist_ok=True)
    warm_up(args, trees, commits, out)
    records = []
    with open(out / RUNS_FILE, "a") as log:
        for round_ in range(1, args.rounds + 1):
            order = SIDES if round_ % 2 else SIDES[::-1]
            for name in args.suites:
                for position, side in enumerate(order, 1):
                    raw = out / RAW_DIR / f"r{round_}_{name}_{side}.txt"
                    record = {"side": side, "ref": refs[side], "commit": commits[side], "suite": name,
                              "round": round_, "position": position,
                              **run_one(args.python, trees[side], SUITES[name], args, raw),
                              "raw": str(raw.relative_to(out))}
                    log.write(json.dumps(record) + "\n")
                    log.flush()
                    records.append(record)
                    shown = ", ".join(f"{k} {_number(v)}" for k, v in record.get("figures", {}).items())
                    print(f"round {round_} {name} {side}: {shown or record.get('error')} ({record['wall_s']:.0f} s)",
                          flush=True)
    return records


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="tools/ab_benchmark.py", description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--base", help="the commit measured against (e.g. 3cd871e, the one before issue 40)")
    parser.add_argument("--head", default="HEAD", help="the commit measured (default HEAD)")
    parser.add_argument("--rounds", type=int, default=3, help="rounds, each every suite on both commits (default 3)")
    parser.add_argument("--suites", nargs="+", choices=list(SUITES), default=list(DEFAULT_SUITES),
                        help="the suites (default all: sim, train = train --config async, policy)")
    parser.add_argument("--out", type=Path, required=True, help="folder of runs.jsonl, raw/ and summary.md")
    parser.add_argument("--worktrees", type=Path, default=Path("runs/ab/worktrees"),
                        help="folder of the commits' worktrees (default runs/ab/worktrees)")
    parser.add_argument("--python", default=sys.executable, help="the interpreter of the runs (default: this one)")
    parser.add_argument("--sim-steps", type=int, default=2000, help="sim --steps (default 2000)")
    parser.add_argument("--train-updates", type=int, default=15, help="train --updates (default 15)")
    parser.add_argument("--policy-decisions", type=int, default=300, help="policy --decisions (default 300; >= 200)")
    parser.add_argument("--timeout", type=float, default=900.0, help="seconds a run may take (default 900)")
    parser.add_argument("--summary-only", action="store_true", help="print the table of --out's runs; run nothing")
    args = parser.parse_args(argv)
    out = args.out.resolve()
    if args.summary_only:
        print(markdown_table(read_records(out / RUNS_FILE)), end="")
        return 0
    if not args.base:
        parser.error("--base is required (unless --summary-only)")
    if args.rounds < 1 or args.sim_steps < 1 or args.train_updates < 1 or args.policy_decisions < 200:
        parser.error("--rounds, --sim-steps and --train-updates must be at least 1, --policy-decisions at least 200")
    if (out / RUNS_FILE).exists() and (out / RUNS_FILE).stat().st_size:
        parser.error(f"{out / RUNS_FILE} already holds runs: choose a new --out (--summary-only reprints its table)")
    args.suites = list(dict.fromkeys(args.suites))
    args.worktrees = args.worktrees.resolve()
    out.mkdir(parents=True, exist_ok=True)
    records = measure(args, out)
    table = markdown_table(records)
    (out / SUMMARY_FILE).write_text(table)
    print(f"\n{table}\nruns: {out / RUNS_FILE}; table: {out / SUMMARY_FILE}", end="\n")
    return 1 if any(r.get("error") for r in records) else 0


if __name__ == "__main__":
    sys.exit(main())
