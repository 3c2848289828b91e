"""The policy at the peak of a run's training curve: ``best_policy.safetensors`` beside ``policy.safetensors``.

Why: a run's last policy is not always its best — a pure-RL driving seed climbed to 33 per car and episode at 1.6 M
env steps and ended at 7 (docs/results.md, "Driving"). The paper's statistic is the best moving average of the
training return, which only says how high the curve went; keeping the policy from that moment lets a held-out
evaluation say how good that policy really is. What the peak is: the best ``window``-window moving average of
``episode/return`` over the logging windows that had finished episodes — exactly what ``dynenv-eval
training-best RUN --window W`` reads from the same run's ``metrics.csv`` afterwards, so the file is the policy at
the env step that command prints.

The file is a policy file like any other (``dynenv-eval`` and the policy node load it); its meta adds
``best_moving_average`` and ``best_window``. Resuming a run restores the moving average's last windows from
``metrics.csv`` (steps up to the checkpoint's) and the best so far from the file's meta. (After a kill, the stretch
since the last checkpoint is trained again and logged again; a policy kept in the lost stretch stays kept, though
``training-best``, where a later row of a step wins, no longer sees the peak it was kept for.)
"""
from __future__ import annotations

import math
from collections import deque
from pathlib import Path
from typing import Any, Mapping

from dynenv_ros.agent.checkpoint import load_policy, save_policy
from dynenv_ros.learning.run.metrics import CSV_NAME, read_metrics, series_by_step

BEST_POLICY = "best_policy.safetensors"
METRIC = "episode/return"


class BestPolicy:
    """Tracks the moving average of the logged episode returns; ``observe`` says when the policy should be kept."""

    def __init__(self, window: int, recent: list[float] | None = None, best: float = -math.inf) -> None:
        if isinstance(window, bool) or not isinstance(window, int) or window < 1:
            raise ValueError(f"window must be a positive integer, got {window!r}")
        self.window = window
        self.recent: deque[float] = deque(recent or [], maxlen=window)
        self.best = best

    def observe(self, value: float) -> float | None:
        """One logging window's mean episode return → the new best moving average when it beats every earlier
        one (the policy now is the one to keep), else None. No moving average before ``window`` windows."""
        if not math.isfinite(value):
            return None
        self.recent.append(float(value))
        if len(self.recent) < self.window:
            return None
        average = sum(self.recent) / self.window
        if average > self.best:
            self.best = average
            return average
        return None

    def save(self, run_dir: Path, agent: Any, meta: Mapping[str, Any], average: float) -> None:
        """Write ``agent`` as the kept policy file (atomic) with the moving average it was kept for."""
        save_policy(agent, Path(run_dir) / BEST_POLICY, {**meta, "best_moving_average": average,
                                                         "best_window": self.window})

    @classmethod
    def resume(cls, run_dir: Path, window: int, env_steps: int) -> "BestPolicy":
        """The tracker of a resumed run: its last ``window`` logged returns up to ``env_steps`` (a later row of a
        step wins, as ``dynenv-eval training-best`` reads it) and the best kept so far (the file's meta, when its
        window is this one)."""
        recent: list[float] = []
        log = Path(run_dir) / CSV_NAME
        series = read_metrics(log).get(METRIC) if log.is_file() else None
        if series is not None:
            steps, values = series_by_step(series)
            recent = [v for s, v in zip(steps, values) if s <= env_steps][-window:]
        return cls(window, recent, kept_average(Path(run_dir) / BEST_POLICY, window))


def kept_average(path: Path, window: int) -> float:
    """The moving average a kept best policy was saved for; −inf when there is none, it cannot be read, or it was
    kept over another window."""
    if not path.is_file():
        return -math.inf
    try:
        _, meta = load_policy(path)
    except ValueError:
        return -math.inf
    if meta.get("best_window") != window or not isinstance(meta.get("best_moving_average"), (int, float)):
        return -math.inf
    return float(meta["best_moving_average"])


__all__ = ["BestPolicy", "BEST_POLICY", "kept_average"]
