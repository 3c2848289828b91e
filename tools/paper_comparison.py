#!/usr/bin/env python3
"""The paper's main comparison from finished training runs: evaluations, tables, BEST and training curves.

Usage::

    .venv/bin/python tools/paper_comparison.py --runs runs/results --episodes 10 --out runs/results/eval \\
        --images docs/images/results --markdown runs/results/eval/tables.md [--workers 2] [--draws 2000]

What it does:

1. Finds the runs under ``--runs`` (folders with a ``config.json``); a run without ``summary.json`` is unfinished
   and skipped, as is one without ``policy.safetensors`` (both listed in the Markdown). Each finished run's
   ``policy.safetensors`` is evaluated against ``random`` and against ``scripted`` with ONE evaluation seed: its
   training seed (the training seed is the statistical unit; two runs with the same seed meet the same env seeds,
   common random numbers). The ``random`` team itself is evaluated with seeds 0, 1, 2 (its three units). All
   with ``evaluation.soccer.evaluate``: ``--episodes`` episodes per seed, sides alternating, 2v2, realistic
   perception, stochastic policies. Each evaluation goes to ``--out/<unit>_vs_<opponent>.json`` (unit: the run
   folder's name, or ``random_s<seed>``) and is reused on a re-run when its settings, seed, opponent and policy
   file (SHA-256) still match, so only what is new is evaluated. ``--workers`` processes (spawn context, one
   torch thread each) run the evaluations in parallel.
2. Per group (random, baseline, pred, recon — the run's ``variant``) and opponent, the per-seed results are
   merged into ``--out/group_<group>_vs_<opponent>.json`` (a ``dynenv_eval/1`` file whose ``per_seed`` rows are
   the units, in seed order), the input of ``dynenv-eval compare``.
3. Markdown (``--markdown``): (a) against random: n seeds and mean ± sd over seeds of the total reward per robot
   and episode, of each reward term, of the paper metric, and the group's mean total over random's; (b) against
   scripted: goals for and against and W/D/L summed over seeds and episodes, goal difference and total reward
   per episode (mean ± sd over seeds); (c) BEST (``evaluation.best``, seeds as the unit) on the total reward against
   random for random→baseline, random→pred, baseline→pred and pred→recon, and on the goal difference against
   scripted for baseline→pred (a comparison with a group of fewer than 2 seeds is skipped and listed); one PNG
   per comparison in ``--images`` (``best_<a>_vs_<b>.png``; ``best_<a>_vs_<b>_goal_difference.png``) and the
   posterior summary in ``--out/best_<a>_vs_<b>[_goal_difference].json``; (d) the training curves
   (``--images/training_curves.png``: ``episode/return`` and ``episode/paper_metric`` against env steps, a thin
   line per run and a thick mean per variant over the env steps all its runs reached, linearly interpolated onto
   a common grid, and ``speed/env_steps_per_second``); (e) the ``dynenv-eval`` command lines equivalent to what
   ran.

The training runs' ``algorithm`` must be the same for all finished runs (else pick one with ``--algorithm``).
"""
from __future__ import annotations

import argparse
import json
import math
import os
import re
import shlex
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from dynenv_ros.evaluation.results import FORMAT, summarize  # noqa: E402
from dynenv_ros.evaluation.soccer import RESULTS, SEED_METRICS  # noqa: E402

RANDOM = "random"
OPPONENTS = ("random", "scripted")
RANDOM_SEEDS = (0, 1, 2)
GROUP_ORDER = ("random", "baseline", "pred", "recon", "pred+teacher")   # "+teacher": imitation on (not in the paper)
TERMS = ("primary", "rule", "auxiliary", "observation")
# (baseline group, proposal group) on the total reward against random; goal difference against scripted.
TOTAL_COMPARISONS = (("random", "baseline"), ("random", "pred"), ("baseline", "pred"), ("pred", "recon"),
                     ("random", "pred+teacher"), ("pred", "pred+teacher"))
GOAL_COMPARISONS = (("baseline", "pred"), ("pred", "pred+teacher"))
CURVE_METRICS = (("episode/return", "episode return (per robot)"),
                 ("episode/paper_metric", "episode paper metric (per robot)"),
                 ("speed/env_steps_per_second", "env steps per second"))
COLORS = {"baseline": "#4c72b0", "pred": "#dd8452", "recon": "#55a868", "pred+teacher": "#c44e52"}
RUN_NAME = re.compile(r"^(?P<algorithm>[a-z0-9]+)_(?P<variant>.+)_s(?P<seed>\d+)$")


# -- runs and jobs -----------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Run:
    name: str
    path: Path
    algorithm: str
    variant: str
    seed: int
    summary: dict = field(default_factory=dict, compare=False)

    @property
    def policy(self) -> Path:
        return self.path / "policy.safetensors"


@dataclass(frozen=True)
class Settings:
    episodes: int
    players_per_team: int = 2
    perception: str = "realistic"
    sides: str = "alternate"
    greedy: bool = False
    episode_seconds: float | None = None

    @property
    def env_config(self) -> dict[str, Any]:
        return {} if self.episode_seconds is None else {"episode_seconds": float(self.episode_seconds)}


@dataclass(frozen=True)
class Job:
    """One evaluation: ``policy`` (a policy file path or "random") against ``opponent`` with one seed."""
    unit: str
    group: str
    seed: int
    policy: str
    opponent: str
    out: Path

    def command(self, settings: Settings) -> str:
        words = ["dynenv-eval", self.policy, "--opponent", self.opponent, "--episodes", str(settings.episodes),
                 "--seeds", str(self.seed), "--players-per-team", str(settings.players_per_team),
                 "--perception", settings.perception, "--sides", settings.sides]
        if settings.episode_seconds is not None:
            words += ["--episode-seconds", f"{settings.episode_seconds:g}"]
        if settings.greedy:
            words.append("--greedy")
        words += ["--torch-threads", "1", "--quiet", "--out", str(self.out)]
        return shlex.join(words)


def find_runs(runs_dir: Path, algorithm: str | None = None) -> tuple[list[Run], list[tuple[str, str]]]:
    """(finished runs sorted by group and seed, [(folder, why skipped)]). A run is a folder with ``config.json``."""
    runs, skipped = [], []
    for path in sorted(p for p in Path(runs_dir).iterdir() if p.is_dir() and (p / "config.json").is_file()):
        try:
            config = json.loads((path / "config.json").read_text())
        except (OSError, json.JSONDecodeError) as error:
            skipped.append((path.name, f"config.json unreadable: {error}"))
            continue
        match = RUN_NAME.match(path.name)
        variant = config.get("variant") or (match and match["variant"])
        if variant and config.get("teacher"):      # imitation of a scripted teacher: a group of its own
            variant = f"{variant}+teacher"
        seed = config.get("seed", match and int(match["seed"]))
        algo = config.get("algorithm") or (match and match["algorithm"]) or "?"
        if not variant or seed is None:
            skipped.append((path.name, "no variant or seed in config.json"))
            continue
        if algorithm is not None and algo != algorithm:
            skipped.append((path.name, f"algorithm {algo}, not {algorithm}"))
            continue
        if not (path / "summary.json").is_file():
            skipped.append((path.name, "unfinished (no summary.json)"))
            continue
        if not (path / "policy.safetensors").is_file():
            skipped.append((path.name, "no policy.safetensors"))
            continue
        try:
            summary = json.loads((path / "summary.json").read_text())
        except (OSError, json.JSONDecodeError):
            summary = {}
        runs.append(Run(path.name, path, str(algo), str(variant), int(seed), summary))
    algorithms = sorted({r.algorithm for r in runs})
    if len(algorithms) > 1:
        raise ValueError(f"finished runs of several algorithms ({', '.join(algorithms)}): choose one with "
                         "--algorithm")
    return sorted(runs, key=lambda r: (group_rank(r.variant), r.seed, r.name)), skipped


def group_rank(group: str) -> tuple[int, str]:
    return (GROUP_ORDER.index(group), "") if group in GROUP_ORDER else (len(GROUP_ORDER), group)


def plan_jobs(runs: Sequence[Run], out_dir: Path) -> list[Job]:
    """The checkpoint evaluations first (the slow ones), then the random team's."""
    jobs = [Job(run.name, run.variant, run.seed, str(run.policy), opponent, out_dir / f"{run.name}_vs_{opponent}.json")
            for run in runs for opponent in OPPONENTS]
    jobs += [Job(f"random_s{seed}", RANDOM, seed, RANDOM, opponent, out_dir / f"random_s{seed}_vs_{opponent}.json")
             for seed in RANDOM_SEEDS for opponent in OPPONENTS]
    return jobs


def cache_problem(job: Job, settings: Settings, sha: str | None) -> str | None:
    """None when ``job.out`` holds this evaluation already, else why it must be (re)done."""
    from dynenv_ros.evaluation.results import load_evaluation
    if not job.out.is_file():
        return "new"
    try:
        data = load_evaluation(job.out)
    except ValueError as error:
        return str(error)
    s = data.get("settings", {})
    wanted = {"episodes": settings.episodes, "seeds": [job.seed], "players_per_team": settings.players_per_team,
              "perception": settings.perception, "sides": settings.sides, "greedy": settings.greedy,
              "env_config": settings.env_config}
    for key, value in wanted.items():
        if s.get(key) != value:
            return f"{key} was {s.get(key)!r}, now {value!r}"
    if data.get("opponent", {}).get("spec") != job.opponent:
        return "another opponent"
    evaluated = data.get("evaluated", {})
    if sha is None:
        if evaluated.get("kind") != RANDOM:
            return "not the random team"
    elif evaluated.get("sha256") != sha:
        return "the policy file changed"
    return None


def _worker_init() -> None:
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    import torch
    torch.set_num_threads(1)


def evaluate_job(job: Job, settings: Settings) -> tuple[Job, float]:
    """Evaluate one job and write its JSON (also the worker function: module level, so spawn can pickle it)."""
    from dynenv_ros.evaluation.results import write_json
    from dynenv_ros.evaluation.soccer import evaluate
    start = time.perf_counter()
    result = evaluate(job.policy, job.opponent, episodes=settings.episodes, seeds=[job.seed],
                      players_per_team=settings.players_per_team, perception=settings.perception,
                      sides=settings.sides, greedy=settings.greedy, env_config=settings.env_config, torch_threads=1)
    write_json(result, job.out)
    return job, time.perf_counter() - start


def _evaluate_star(args: tuple[Job, Settings]) -> tuple[Job, float]:
    return evaluate_job(*args)


def run_jobs(jobs: Sequence[Job], settings: Settings, workers: int = 1,
             log: Callable[[str], None] = print) -> dict[Path, str]:
    """Evaluate every job whose JSON is missing or stale; ``{out: "cached" | "evaluated"}``."""
    from dynenv_ros.agent.checkpoint import sha256
    status: dict[Path, str] = {}
    todo = []
    hashes: dict[str, str] = {}
    for job in jobs:
        sha = None if job.policy == RANDOM else hashes.setdefault(job.policy, sha256(job.policy))
        problem = cache_problem(job, settings, sha)
        if problem is None:
            status[job.out] = "cached"
        else:
            if problem != "new":
                log(f"re-evaluating {job.out.name}: {problem}")
            todo.append(job)
    if not todo:
        log(f"all {len(jobs)} evaluations cached")
        return status
    log(f"{len(jobs) - len(todo)} evaluations cached, {len(todo)} to run with {min(workers, len(todo))} worker(s)")
    start = time.perf_counter()
    done = 0

    def report(job: Job, seconds: float) -> None:
        nonlocal done
        done += 1
        status[job.out] = "evaluated"
        log(f"[{done}/{len(todo)}] {job.unit} vs {job.opponent}: {seconds:.1f} s "
            f"(elapsed {time.perf_counter() - start:.0f} s)")

    if workers <= 1 or len(todo) == 1:
        _worker_init()
        for job in todo:
            report(*evaluate_job(job, settings))
    else:
        import multiprocessing
        context = multiprocessing.get_context("spawn")
        with context.Pool(min(workers, len(todo)), initializer=_worker_init) as pool:
            for job, seconds in pool.imap_unordered(_evaluate_star, [(job, settings) for job in todo]):
                report(job, seconds)
    return status


# -- merged group results ----------------------------------------------------------------------------------------
def load_units(jobs: Sequence[Job]) -> dict[str, dict[str, list[tuple[Job, dict]]]]:
    """group → opponent → [(job, evaluation JSON)], groups in GROUP_ORDER, units by seed."""
    from dynenv_ros.evaluation.results import load_evaluation
    out: dict[str, dict[str, list[tuple[Job, dict]]]] = {}
    for job in sorted(jobs, key=lambda j: (group_rank(j.group), j.seed, j.unit)):
        out.setdefault(job.group, {}).setdefault(job.opponent, []).append((job, load_evaluation(job.out)))
    return out


def merge_group(group: str, opponent: str, units: Sequence[tuple[Job, dict]]) -> dict[str, Any]:
    """One ``dynenv_eval/1`` result of a group: the units' per-seed rows (one per unit) and episodes in order."""
    per_seed = [row for _, data in units for row in data["per_seed"]]
    episodes = [dict(record, unit=job.unit) for job, data in units for record in data["episodes"]]
    settings = dict(units[0][1]["settings"])
    settings["seeds"] = [int(row["seed"]) for row in per_seed]
    counts = {"episodes": len(episodes)}
    for result, key in zip(RESULTS, ("wins", "draws", "losses")):
        counts[key] = sum(r["result"] == result for r in episodes)
    return {"format": FORMAT, "settings": settings,
            "evaluated": {"spec": group, "kind": "group",
                          "units": [{"unit": job.unit, "file": job.out.name, **data["evaluated"]}
                                    for job, data in units]},
            "opponent": units[0][1]["opponent"], "episodes": episodes, "per_seed": per_seed,
            "summary": summarize(per_seed, SEED_METRICS), "counts": counts}


def write_groups(units: Mapping[str, Mapping[str, Sequence[tuple[Job, dict]]]], out_dir: Path
                 ) -> dict[tuple[str, str], Path]:
    from dynenv_ros.evaluation.results import write_json
    paths = {}
    for group, by_opponent in units.items():
        for opponent, items in by_opponent.items():
            path = out_dir / f"group_{group}_vs_{opponent}.json"
            write_json(merge_group(group, opponent, items), path)
            paths[group, opponent] = path
    return paths


def values(units: Sequence[tuple[Job, dict]], metric: str) -> list[float]:
    assert metric in SEED_METRICS, metric
    return [float(row[metric]) for _, data in units for row in data["per_seed"]]


def mean_sd(xs: Sequence[float]) -> tuple[float, float]:
    a = np.asarray(xs, float)
    return float(a.mean()), float(a.std(ddof=1)) if len(a) > 1 else float("nan")


def fmt_mean_sd(xs: Sequence[float]) -> str:
    mean, sd = mean_sd(xs)
    return f"{mean:.4g} ± {sd:.2g}" if len(xs) > 1 else f"{mean:.4g}"


# -- tables ------------------------------------------------------------------------------------------------------
def table_random(units: Mapping[str, Mapping[str, Sequence[tuple[Job, dict]]]]) -> str:
    columns = [("total", "total")] + [(t, t) for t in TERMS] + [("paper metric", "paper_metric")]
    lines = ["| group | n seeds | " + " | ".join(name for name, _ in columns) + " | total / random's |",
             "|---|---:|" + "---:|" * (len(columns) + 1)]
    random_mean = mean_sd(values(units[RANDOM]["random"], "total"))[0] if RANDOM in units else float("nan")
    for group, by_opponent in units.items():
        items = by_opponent.get("random", [])
        if not items:
            continue
        cells = [fmt_mean_sd(values(items, metric)) for _, metric in columns]
        mean = mean_sd(values(items, "total"))[0]
        ratio = mean / random_mean if random_mean != 0.0 and math.isfinite(random_mean) else float("nan")
        lines.append(f"| {group} | {len(items)} | " + " | ".join(cells) + f" | {ratio:.3g} |")
    return "\n".join(lines)


def ratio_note(units: Mapping[str, Mapping[str, Sequence[tuple[Job, dict]]]]) -> list[str]:
    if RANDOM not in units or "random" not in units[RANDOM]:
        return ["", "(No random-team evaluation: no ratio.)"]
    mean = mean_sd(values(units[RANDOM]["random"], "total"))[0]
    if mean > 0:
        return []
    return ["", f"Note: the random team's mean total is {mean:.4g} (not positive), so the ratio column does not "
            "read as \"times better\"; compare the totals themselves."]


def table_scripted(units: Mapping[str, Mapping[str, Sequence[tuple[Job, dict]]]]) -> str:
    lines = ["| group | n seeds | episodes | goals for | goals against | W/D/L | goal difference / episode | "
             "total |", "|---|---:|---:|---:|---:|---|---:|---:|"]
    for group, by_opponent in units.items():
        items = by_opponent.get("scripted", [])
        if not items:
            continue
        episodes = [r for _, data in items for r in data["episodes"]]
        gf = sum(int(r["goals_for"]) for r in episodes)
        ga = sum(int(r["goals_against"]) for r in episodes)
        wdl = "/".join(str(sum(r["result"] == res for r in episodes)) for res in RESULTS)
        lines.append(f"| {group} | {len(items)} | {len(episodes)} | {gf} | {ga} | {wdl} | "
                     f"{fmt_mean_sd(values(items, 'goal_difference'))} | {fmt_mean_sd(values(items, 'total'))} |")
    return "\n".join(lines)


@dataclass
class Comparison:
    a: str
    b: str
    metric: str
    opponent: str
    png: Path
    json: Path
    result: Any = None
    skipped: str | None = None

    @property
    def label(self) -> str:
        return f"{self.a} → {self.b}"


def run_best(units: Mapping[str, Mapping[str, Sequence[tuple[Job, dict]]]], images: Path, out_dir: Path,
             draws: int, tune: int, chains: int, seed: int, log: Callable[[str], None] = print
             ) -> list[Comparison]:
    from dynenv_ros.evaluation.best import best, plot_posterior
    plan = [(a, b, "total", "random", "") for a, b in TOTAL_COMPARISONS]
    plan += [(a, b, "goal_difference", "scripted", "_goal_difference") for a, b in GOAL_COMPARISONS]
    out = []
    for a, b, metric, opponent, suffix in plan:
        c = Comparison(a, b, metric, opponent, images / f"best_{a}_vs_{b}{suffix}.png",
                       out_dir / f"best_{a}_vs_{b}{suffix}.json")
        out.append(c)
        n = {g: len(units.get(g, {}).get(opponent, [])) for g in (a, b)}
        short = [f"{g} has {n[g]} seed{'s' if n[g] != 1 else ''}" for g in (a, b) if n[g] < 2]
        if short:
            c.skipped = "; ".join(short) + " (BEST needs ≥ 2)"
            log(f"BEST {c.label} ({metric} vs {opponent}) skipped: {c.skipped}")
            continue
        y1, y2 = values(units[a][opponent], metric), values(units[b][opponent], metric)
        start = time.perf_counter()
        try:
            c.result, samples = best(y1, y2, draws=draws, tune=tune, chains=chains, random_seed=seed,
                                     return_samples=True)
        except ValueError as error:
            c.skipped = str(error)
            log(f"BEST {c.label} ({metric} vs {opponent}) skipped: {error}")
            continue
        plot_posterior(c.result, samples, c.png, labels=(a, b), metric=f"{metric.replace('_', ' ')} vs {opponent}")
        c.json.write_text(json.dumps({"a": a, "b": b, "metric": metric, "opponent": opponent, "values_a": y1,
                                      "values_b": y2, **c.result.as_dict()}, indent=1) + "\n")
        log(f"BEST {c.label} ({metric} vs {opponent}): P({b} > {a}) = {c.result.p_improvement:.3f} "
            f"({time.perf_counter() - start:.1f} s)")
    return out


def table_best(comparisons: Sequence[Comparison], markdown: Path) -> str:
    lines = ["| comparison | metric | n seeds | difference: mean (median) | 95 % HDI | effect size (95 % HDI) | "
             "P(improvement) | max r̂ | divergences | plot |",
             "|---|---|---:|---:|---|---|---:|---:|---:|---|"]
    skipped = []
    for c in comparisons:
        if c.result is None:
            skipped.append(f"- {c.label} ({c.metric.replace('_', ' ')} vs {c.opponent}): skipped — {c.skipped}")
            continue
        r = c.result
        lo, hi = r.difference_hdi
        elo, ehi = r.effect_size_hdi
        link = os.path.relpath(c.png, markdown.parent)
        lines.append(f"| {c.label} | {c.metric.replace('_', ' ')} vs {c.opponent} | {r.n1}, {r.n2} | "
                     f"{r.difference_mean:.4g} ({r.difference_median:.4g}) | [{lo:.4g}, {hi:.4g}] | "
                     f"{r.effect_size_mean:.3g} "
                     f"[{elo:.3g}, {ehi:.3g}] | {r.p_improvement:.3f} | {r.max_r_hat:.3f} | {r.divergences} | "
                     f"[{c.png.name}]({link}) |")
    text = "\n".join(lines) if len(lines) > 2 else "No comparison had two groups of at least 2 seeds."
    return text + ("\n\n" + "\n".join(skipped) if skipped else "")


# -- training curves ---------------------------------------------------------------------------------------------
def clean_series(steps: Sequence[int], vals: Sequence[float]) -> tuple[np.ndarray, np.ndarray]:
    """Strictly increasing steps: a resumed run repeats the steps after its last checkpoint; the later rows win."""
    out_s: list[int] = []
    out_v: list[float] = []
    for s, v in zip(steps, vals):
        while out_s and out_s[-1] >= s:
            out_s.pop()
            out_v.pop()
        out_s.append(s)
        out_v.append(v)
    return np.asarray(out_s, float), np.asarray(out_v, float)


def mean_curve(series: Sequence[tuple[np.ndarray, np.ndarray]], points: int = 200
               ) -> tuple[np.ndarray, np.ndarray] | None:
    """Mean of the runs' curves, linearly interpolated onto a grid over the steps every run reached."""
    series = [(s, v) for s, v in series if len(s)]
    if not series:
        return None
    lo, hi = max(s[0] for s, _ in series), min(s[-1] for s, _ in series)
    if hi < lo:
        return None
    grid = np.linspace(lo, hi, points) if hi > lo else np.array([lo])
    return grid, np.mean([np.interp(grid, s, v) for s, v in series], axis=0)


def plot_training_curves(runs: Sequence[Run], png: Path) -> Path | None:
    import matplotlib
    matplotlib.use("Agg")
    from matplotlib.figure import Figure
    from dynenv_ros.learning.run.metrics import read_metrics
    data = {}
    for run in runs:
        if (run.path / "metrics.csv").is_file():
            data[run.name] = (run, read_metrics(run.path / "metrics.csv"))
    if not data:
        return None
    fig = Figure(figsize=(15, 4.2), layout="constrained")
    axes = fig.subplots(1, len(CURVE_METRICS))
    variants = sorted({run.variant for run, _ in data.values()}, key=group_rank)
    palette = ["#c44e52", "#8172b3", "#937860", "#da8bc3", "#8c8c8c"]
    colors = {v: COLORS.get(v) or palette[i % len(palette)] for i, v in enumerate(variants)}
    for ax, (metric, title) in zip(axes, CURVE_METRICS):
        for variant in variants:
            series = []
            for run, metrics in data.values():
                if run.variant != variant or metric not in metrics:
                    continue
                s, v = clean_series(*metrics[metric])
                series.append((s, v))
                ax.plot(s, v, color=colors[variant], linewidth=0.7, alpha=0.4)
            mean = mean_curve(series)
            if mean is not None:
                ax.plot(*mean, color=colors[variant], linewidth=2.5, label=f"{variant} (mean of {len(series)})")
        ax.set_title(title)
        ax.set_xlabel("env steps")
        ax.grid(alpha=0.3)
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize=8, frameon=False)
    fig.suptitle("Training curves: thin = one run, thick = mean per variant (interpolated over the steps all its "
                 "runs reached)")
    fig.savefig(png, format="png", dpi=100)
    return png


# -- markdown ----------------------------------------------------------------------------------------------------
def markdown_text(argv: Sequence[str], settings: Settings, runs: Sequence[Run], skipped: Sequence[tuple[str, str]],
                  jobs: Sequence[Job], units: Mapping, groups: Mapping[tuple[str, str], Path],
                  comparisons: Sequence[Comparison], curves: Path | None, markdown: Path,
                  best_args: Mapping[str, int]) -> str:
    length = "the env's 120 s" if settings.episode_seconds is None else f"{settings.episode_seconds:g} s"
    plural = "s" if settings.episodes != 1 else ""
    out = ["# Paper comparison", "",
           f"Generated by `{shlex.join(['.venv/bin/python', 'tools/paper_comparison.py', *argv])}`.", "",
           f"Each evaluation: {settings.episodes} episode{plural} of {length}, {settings.players_per_team}v"
           f"{settings.players_per_team}, {settings.perception} perception, "
           f"{'greedy' if settings.greedy else 'stochastic'} policies, sides alternating (the evaluated team is "
           "team A in even episodes, B in odd ones). One evaluation seed per trained policy, equal to its training "
           f"seed; the random team with seeds {', '.join(map(str, RANDOM_SEEDS))}. The seed is the statistical unit: "
           "numbers are per robot and episode, averaged over a seed's episodes, then mean ± sd over seeds.", "",
           "## Runs", "", "| run | variant | seed | env steps | wall minutes | policy sha256 |",
           "|---|---|---:|---:|---:|---|"]
    from dynenv_ros.agent.checkpoint import sha256
    for run in runs:
        steps = run.summary.get("env_steps", "?")
        wall = run.summary.get("wall_seconds")
        out.append(f"| {run.name} | {run.variant} | {run.seed} | {steps} | "
                   f"{'?' if wall is None else f'{wall / 60:.1f}'} | `{sha256(run.policy)[:12]}` |")
    if not runs:
        out.append("| (no finished runs) | | | | | |")
    if skipped:
        out += ["", "Skipped: " + "; ".join(f"{name} ({why})" for name, why in skipped) + "."]
    missing = [g for g in GROUP_ORDER if g not in units]
    if missing:
        out += ["", f"No finished runs for: {', '.join(missing)}."]
    out += ["", "## (a) Against random", "",
            "Total reward and reward terms per robot and episode; the paper metric is the positive reward minus the "
            "observation reward; the last column is the group's mean total over the random team's.", "",
            table_random(units), *ratio_note(units), "",
            "## (b) Against scripted (keeper_and_chasers)", "",
            "Goals and W/D/L summed over seeds and episodes; goal difference and total reward per episode, mean ± sd "
            "over seeds.", "", table_scripted(units), "",
            "## (c) BEST (Kruschke 2013), seeds as the unit", "",
            f"PyMC NUTS, {best_args['chains']} chains × {best_args['draws']} draws (tune {best_args['tune']}), "
            f"sampler seed {best_args['seed']}. Difference of means μ_b − μ_a (posterior mean and median; with few "
            "seeds the Student-t posterior has long tails, so the two can differ); P(improvement) = P(μ_b > μ_a).",
            "", table_best(comparisons, markdown), ""]
    if curves is not None:
        out += ["## Training curves", "", f"![training curves]({os.path.relpath(curves, markdown.parent)})", ""]
    out += ["## Equivalent commands", "",
            "Each evaluation (the tool ran them through `evaluation.soccer.evaluate` with the same arguments):", "",
            "```sh", *[job.command(settings) for job in jobs], "```", "",
            "The group files (`group_<group>_vs_<opponent>.json`) concatenate the per-seed files above in seed "
            "order; BEST on them prints the same numbers (add `--png FILE` for the plot; the tool's own plots "
            "are labelled with the group names):", "", "```sh"]
    for c in comparisons:
        if c.result is None:
            continue
        words = ["dynenv-eval", "compare", str(groups[c.a, c.opponent]), str(groups[c.b, c.opponent]),
                 "--metric", c.metric, "--draws", str(best_args["draws"]), "--tune", str(best_args["tune"]),
                 "--chains", str(best_args["chains"]), "--seed", str(best_args["seed"])]
        out.append(shlex.join(words))
    out += ["```", ""]
    return "\n".join(out)


# -- command line ------------------------------------------------------------------------------------------------
def positive_int(text: str) -> int:
    value = int(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be at least 1, got {value}")
    return value


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--runs", type=Path, required=True, help="folder holding the run folders")
    p.add_argument("--episodes", type=positive_int, required=True, help="episodes per seed")
    p.add_argument("--out", type=Path, required=True, help="evaluation JSON folder (cache; created)")
    p.add_argument("--images", type=Path, required=True, help="PNG folder (created)")
    p.add_argument("--markdown", type=Path, required=True, help="Markdown file to write")
    p.add_argument("--workers", type=positive_int, default=1, help="evaluation processes (default 1)")
    p.add_argument("--draws", type=positive_int, default=2000, help="BEST draws per chain (default 2000)")
    p.add_argument("--tune", type=positive_int, default=1000, help="BEST tuning steps (default 1000)")
    p.add_argument("--chains", type=positive_int, default=2, help="BEST chains (default 2)")
    p.add_argument("--best-seed", type=int, default=0, help="BEST sampler seed (default 0)")
    p.add_argument("--episode-seconds", type=float, help="episode length (default: the env's 120 s)")
    p.add_argument("--algorithm", help="only runs of this training algorithm (e.g. ppo)")
    return p


def main(argv: Sequence[str] | None = None, log: Callable[[str], None] = print) -> dict[str, Any]:
    argv = list(sys.argv[1:] if argv is None else argv)
    args = parser().parse_args(argv)
    start = time.perf_counter()
    settings = Settings(episodes=args.episodes, episode_seconds=args.episode_seconds)
    for folder in (args.out, args.images, args.markdown.parent):
        folder.mkdir(parents=True, exist_ok=True)
    runs, skipped = find_runs(args.runs, args.algorithm)
    for name, why in skipped:
        log(f"skipping {name}: {why}")
    log(f"{len(runs)} finished runs: {', '.join(r.name for r in runs) or 'none'}")
    jobs = plan_jobs(runs, args.out)
    status = run_jobs(jobs, settings, args.workers, log)
    units = load_units(jobs)
    groups = write_groups(units, args.out)
    best_args = {"draws": args.draws, "tune": args.tune, "chains": args.chains, "seed": args.best_seed}
    comparisons = run_best(units, args.images, args.out, args.draws, args.tune, args.chains, args.best_seed, log)
    curves = plot_training_curves(runs, args.images / "training_curves.png")
    text = markdown_text(argv, settings, runs, skipped, jobs, units, groups, comparisons, curves, args.markdown,
                         best_args)
    args.markdown.write_text(text)
    log(f"wrote {args.markdown} ({time.perf_counter() - start:.0f} s)")
    return {"runs": runs, "skipped": skipped, "jobs": jobs, "status": status, "groups": groups,
            "comparisons": comparisons, "curves": curves, "markdown": args.markdown}


if __name__ == "__main__":
    main()
