"""The paper's driving statistic, from a run's training log: the best moving average of the episode return reached
during training.

The paper reports, per method, the best 10-episode moving average of the training reward — a statistic that can only
flatter (it is a maximum over a noisy curve, on the episodes the policy was trained on). It stands in
docs/results.md beside the held-out evaluation, never instead of it. Our run log (``learning.run.metrics``) holds one
value per logging window: the mean over the car-episodes that finished in it, not each episode. So the moving
average here runs over ``window`` consecutive logged windows; each window already averages several episodes, so the
curve is smoother and its maximum lower than the paper's per-episode one would be on the same run (a conservative
stand-in, said wherever the figure is quoted).
"""
from __future__ import annotations

from pathlib import Path
from typing import Any, Sequence

from dynenv_ros.learning.run.metrics import CSV_NAME, read_metrics, series_by_step

DEFAULT_METRIC = "episode/return"
DEFAULT_WINDOW = 10


def best_moving_average(steps: Sequence[int], values: Sequence[float], window: int) -> tuple[float, int]:
    """(the largest mean of ``window`` consecutive values, the env step of the last value of that stretch)."""
    if isinstance(window, bool) or not isinstance(window, int) or window < 1:
        raise ValueError(f"window must be a positive integer, got {window!r}")
    if len(values) < window:
        raise ValueError(f"{len(values)} logged values, fewer than the window of {window}")
    total = sum(values[:window])
    best, at = total, window - 1
    for k in range(window, len(values)):
        total += values[k] - values[k - window]
        if total > best:
            best, at = total, k
    return best / window, int(steps[at])


def training_statistic(run: str | Path, metric: str = DEFAULT_METRIC, window: int = DEFAULT_WINDOW
                       ) -> dict[str, Any]:
    """The best ``window``-window moving average of ``metric`` in a run's ``metrics.csv`` (``run``: the run folder
    or the file). A resumed run logs again the steps after its last checkpoint: the later row of a step wins."""
    path = Path(run)
    if path.is_dir():
        path = path / CSV_NAME
    if not path.is_file():
        raise ValueError(f"{path}: no training log (metrics.csv) there")
    series = read_metrics(path)
    if metric not in series:
        known = sorted(name for name in series if name.startswith("episode/"))
        raise ValueError(f"{path}: no metric {metric!r} logged (episode metrics: {known})")
    steps, values = series_by_step(series[metric])
    best, at = best_moving_average(steps, values, window)
    return {"path": str(path), "metric": metric, "window": window, "windows": len(steps), "best": best,
            "at_env_steps": at}


__all__ = ["best_moving_average", "training_statistic", "DEFAULT_METRIC", "DEFAULT_WINDOW"]
