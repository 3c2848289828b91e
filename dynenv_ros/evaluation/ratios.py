"""The paper's way of scoring a method: its metric over the random team's on the same games, as a ratio of means.
For a group of training runs (each evaluated on the same seeds as the reference), the interval comes from a
two-level bootstrap: runs drawn with replacement (a method is judged by its runs, not by one lucky seed), and the
evaluation seeds drawn with replacement, paired between the group and the reference (they share the games).
"""
from __future__ import annotations

from typing import Any, Mapping, Sequence

import numpy as np

from dynenv_ros.evaluation.head_to_head import LEVEL, RESAMPLES


def _per_seed(result: Mapping[str, Any], metric: str, name: str) -> dict[int, float]:
    rows = result["per_seed"]
    if any(metric not in row for row in rows):
        raise ValueError(f"{name}: its per-seed rows have no {metric!r}")
    return {int(row["seed"]): float(row[metric]) for row in rows}


def _runs_table(group: Sequence[Mapping[str, Any]], names: Sequence[str], metric: str, seeds: Sequence[int]
                ) -> np.ndarray:
    """runs x seeds of ``metric``, every run evaluated on exactly ``seeds``."""
    runs = []
    for name, result in zip(names, group):
        values = _per_seed(result, metric, name)
        if sorted(values) != list(seeds):
            raise ValueError(f"{name}: evaluated on seeds {sorted(values)}, the others on {list(seeds)}: a group is "
                             f"compared on the same games")
        runs.append([values[s] for s in seeds])
    return np.asarray(runs, float)


def _bootstrap(table: np.ndarray, reference: np.ndarray | None, resamples: int, level: float, seed: int
               ) -> list[float]:
    """The interval of mean(table) (over reference's mean, paired by seed, when given): runs and seeds drawn."""
    rng = np.random.default_rng(seed)
    runs, seeds = table.shape
    run_draws = rng.integers(0, runs, size=(resamples, runs))
    seed_draws = rng.integers(0, seeds, size=(resamples, seeds))
    values = np.array([table[np.ix_(r, s)].mean() for r, s in zip(run_draws, seed_draws)])
    if reference is not None:
        denom = reference[seed_draws].mean(1)
        values = values / np.where(denom > 0, denom, np.nan)
    tail = (1.0 - level) / 2.0
    low, high = np.nanquantile(values, [tail, 1.0 - tail])
    return [float(low), float(high)]


def ratio_of_means(group: Sequence[Mapping[str, Any]], reference: Mapping[str, Any], metric: str = "paper_metric",
                   names: Sequence[str] | None = None, resamples: int = RESAMPLES, level: float = LEVEL,
                   seed: int = 0) -> dict[str, Any]:
    """mean(group's metric) / mean(reference's metric) over the same seeds, with its bootstrap interval."""
    if not group:
        raise ValueError("a ratio needs at least one run")
    names = list(names or [f"run {k}" for k in range(len(group))])
    ref = _per_seed(reference, metric, "reference")
    seeds = sorted(ref)
    table = _runs_table(group, names, metric, seeds)              # runs x seeds
    reference_values = np.asarray([ref[s] for s in seeds], float)
    if reference_values.mean() <= 0:
        raise ValueError(f"the reference's mean {metric} is {reference_values.mean():.4g}: a ratio needs it > 0")
    out: dict[str, Any] = {"metric": metric, "runs": len(table), "seeds": seeds,
                           "group_mean": float(table.mean()), "reference_mean": float(reference_values.mean()),
                           "ratio": float(table.mean() / reference_values.mean()),
                           "per_run_ratio": [float(r.mean() / reference_values.mean()) for r in table],
                           "interval": None, "level": level, "resamples": resamples}
    if len(seeds) >= 2:
        out["interval"] = _bootstrap(table, reference_values, resamples, level, seed)
    return out


def group_mean(group: Sequence[Mapping[str, Any]], metric: str, names: Sequence[str] | None = None,
               resamples: int = RESAMPLES, level: float = LEVEL, seed: int = 0) -> dict[str, Any]:
    """The group's mean of ``metric`` over its runs and their common seeds, with the same bootstrap interval as
    ``ratio_of_means`` (runs and seeds drawn): for a figure the paper reports as an absolute value (driving's reward
    per car and episode), where a ratio to the random driver (near 0) would say nothing."""
    if not group:
        raise ValueError("a group mean needs at least one run")
    names = list(names or [f"run {k}" for k in range(len(group))])
    seeds = sorted(_per_seed(group[0], metric, names[0]))
    table = _runs_table(group, names, metric, seeds)
    return {"metric": metric, "runs": len(table), "seeds": seeds, "group_mean": float(table.mean()),
            "per_run_mean": [float(r.mean()) for r in table], "level": level, "resamples": resamples,
            "interval": _bootstrap(table, None, resamples, level, seed) if len(seeds) >= 2 else None}


def format_ratio(r: Mapping[str, Any], bar: float | None = None) -> str:
    interval = "" if r["interval"] is None else \
        f", 95 % interval [{r['interval'][0]:.2f}x, {r['interval'][1]:.2f}x]"
    line = (f"{r['metric']}: {r['group_mean']:.3f} over the reference's {r['reference_mean']:.3f} = {r['ratio']:.2f}x"
            f"{interval} ({r['runs']} runs x {len(r['seeds'])} seeds; per run "
            f"{', '.join(f'{x:.2f}x' for x in r['per_run_ratio'])})")
    if bar is not None and r["interval"] is not None:
        line += f"; the interval {'lies above' if r['interval'][0] > bar else 'does not lie above'} {bar:g}x"
    return line


def format_mean(r: Mapping[str, Any], bar: float | None = None) -> str:
    interval = "" if r["interval"] is None else f", 95 % interval [{r['interval'][0]:.2f}, {r['interval'][1]:.2f}]"
    line = (f"{r['metric']}: group mean {r['group_mean']:.3f}{interval} ({r['runs']} runs x {len(r['seeds'])} seeds; "
            f"per run {', '.join(f'{x:.2f}' for x in r['per_run_mean'])})")
    if bar is not None and r["interval"] is not None:
        where = ("lies above" if r["interval"][0] > bar else "lies below" if r["interval"][1] < bar else "includes")
        line += f"; the interval {where} {bar:g}"
    return line
