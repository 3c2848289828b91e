"""A head-to-head as a claim can be made from it: wins, draws, losses, goals, and a 95 % interval of the mean
per-game goal difference by a bootstrap over seeds (the seeds are the units: games of one seed share its starts).
"Beats" means that interval lies above 0.

The bootstrap (Efron's percentile interval) draws seeds with replacement, ``resamples`` times, from its own seeded
generator, and takes the mean per-game goal difference of each draw (games weighted equally: every seed has the
same number of games in a dynenv-eval result).
"""
from __future__ import annotations

from typing import Any, Mapping, Sequence

import numpy as np

RESAMPLES = 10_000
LEVEL = 0.95


def bootstrap_interval(per_unit: Sequence[float], weights: Sequence[float] | None = None,
                       resamples: int = RESAMPLES, level: float = LEVEL, seed: int = 0) -> tuple[float, float]:
    """Percentile interval of the weighted mean of ``per_unit`` (one value per unit), units drawn with replacement."""
    values = np.asarray(per_unit, float)
    if values.size < 2:
        raise ValueError("a bootstrap over seeds needs at least 2 seeds")
    w = np.ones_like(values) if weights is None else np.asarray(weights, float)
    rng = np.random.default_rng(seed)
    draws = rng.integers(0, values.size, size=(resamples, values.size))
    means = (values[draws] * w[draws]).sum(1) / w[draws].sum(1)
    tail = (1.0 - level) / 2.0
    low, high = np.quantile(means, [tail, 1.0 - tail])
    return float(low), float(high)


def head_to_head(result: Mapping[str, Any]) -> dict[str, Any]:
    """The head-to-head numbers of a soccer ``dynenv-eval`` result (its ``episodes`` records)."""
    records = result["episodes"]
    by_seed: dict[int, list[int]] = {}
    for r in records:
        by_seed.setdefault(int(r["seed"]), []).append(int(r["goals_for"]) - int(r["goals_against"]))
    sums = [float(sum(v)) for v in by_seed.values()]
    counts = [float(len(v)) for v in by_seed.values()]
    wins = sum(r["result"] == "win" for r in records)
    losses = sum(r["result"] == "loss" for r in records)
    out: dict[str, Any] = {
        "games": len(records), "seeds": len(by_seed), "wins": wins,
        "draws": sum(r["result"] == "draw" for r in records), "losses": losses,
        "goals_for": int(sum(r["goals_for"] for r in records)),
        "goals_against": int(sum(r["goals_against"] for r in records)),
        "goal_difference_per_game": float(sum(sums) / sum(counts)),
        "interval": None, "beats": False, "level": LEVEL, "resamples": RESAMPLES,
    }
    if len(by_seed) >= 2:
        # per-seed means weighted by their game counts = the per-game mean of the drawn seeds' games
        low, high = bootstrap_interval([s / c for s, c in zip(sums, counts)], counts)
        out["interval"] = [low, high]
        out["beats"] = low > 0.0
    return out


def format_head_to_head(h: Mapping[str, Any]) -> str:
    interval = h["interval"]
    spread = "no interval (one seed)" if interval is None else \
        f"95 % interval [{interval[0]:+.3f}, {interval[1]:+.3f}] (bootstrap over {h['seeds']} seeds)"
    verdict = "beats the opponent" if h["beats"] else "does not beat the opponent (interval not above 0)"
    return (f"head-to-head: {h['games']} games, W/D/L {h['wins']} / {h['draws']} / {h['losses']}, goals "
            f"{h['goals_for']} : {h['goals_against']}; goal difference per game {h['goal_difference_per_game']:+.3f}, "
            f"{spread}: {verdict}")
