"""What a training run writes as it goes: every logged scalar to ``metrics.csv`` (long format: one row per scalar,
``env_steps, update, wall_seconds, name, value`` — append-only, so a resumed run simply continues the file) and to
TensorBoard event files under ``tensorboard/``; at the end, PNG training curves (``curves.png``)."""
from __future__ import annotations

import csv
import math
import os
from collections import defaultdict
from pathlib import Path
from typing import Mapping

CSV_NAME = "metrics.csv"
CSV_HEADER = ("env_steps", "update", "wall_seconds", "name", "value")
VALUE_FORMAT = ".6g"            # a scalar as metrics.csv holds it (``as_logged``)
# The curves drawn at the end, in this order (those a run never logged are skipped).
CURVES = ("episode/return", "episode/primary", "episode/rule", "episode/auxiliary", "episode/observation",
          "episode/paper_metric", "train/policy_loss", "train/value_loss", "train/entropy", "train/forward_loss",
          "train/inverse_loss", "train/ltp_loss", "train/localization_loss", "train/reconstruction_loss",
          "train/approx_kl", "train/clip_fraction", "speed/env_steps_per_second")


class RunLogger:
    def __init__(self, run_dir: Path, tensorboard: bool = True) -> None:
        self.run_dir = Path(run_dir)
        self.path = self.run_dir / CSV_NAME
        size = self.path.stat().st_size if self.path.exists() else 0
        ends_cleanly = size == 0 or self.path.read_bytes()[-1:] == b"\n"
        self._file = open(self.path, "a", newline="")
        self._csv = csv.writer(self._file)
        if not ends_cleanly:          # a run killed mid-row: end that row, read_metrics skips it
            self._file.write("\n")
        if size == 0:
            self._csv.writerow(CSV_HEADER)
        self._file.flush()
        self._tb = None
        if tensorboard:
            from torch.utils.tensorboard import SummaryWriter     # imports the tensorboard package
            self._tb = SummaryWriter(str(self.run_dir / "tensorboard"))

    def log(self, env_steps: int, update: int, wall_seconds: float, scalars: Mapping[str, float]) -> None:
        for name, value in scalars.items():
            if value is None or (isinstance(value, float) and math.isnan(value)):
                continue
            self._csv.writerow((env_steps, update, f"{wall_seconds:.3f}", name, format(float(value), VALUE_FORMAT)))
            if self._tb is not None:
                self._tb.add_scalar(name, float(value), env_steps)
        self._file.flush()

    def close(self) -> None:
        self._file.close()
        if self._tb is not None:
            self._tb.close()


def as_logged(value: float) -> float:
    """``value`` as metrics.csv holds it: what a reader of the file (``training-best``) sees."""
    return float(format(float(value), VALUE_FORMAT))


def series_by_step(series: tuple[list[int], list[float]]) -> tuple[list[int], list[float]]:
    """One logged series (``read_metrics``'s) by ascending env step, one value a step: a resumed run logs again the
    steps after its last checkpoint, and the later row of a step wins."""
    by_step = dict(zip(*series))                  # file order: a re-logged step keeps its later value
    steps = sorted(by_step)
    return steps, [by_step[s] for s in steps]


def read_metrics(path: Path) -> dict[str, tuple[list[int], list[float]]]:
    """name → (env steps, values), in file order (a resumed run may repeat steps after its last checkpoint; the
    later rows win when plotted, as they are drawn last)."""
    series: dict[str, tuple[list[int], list[float]]] = defaultdict(lambda: ([], []))
    with open(path, newline="") as handle:
        for row in csv.DictReader(handle):
            try:
                step, value = int(row["env_steps"]), float(row["value"])
            except (TypeError, ValueError, KeyError):      # a row cut short by a kill
                continue
            steps, values = series[row["name"]]
            steps.append(step)
            values.append(value)
    return dict(series)


def plot_curves(run_dir: Path, out: Path | None = None, smooth: int = 10) -> Path:
    """One panel per logged curve of ``CURVES`` (moving average over ``smooth`` points drawn over the raw
    values) → ``curves.png`` in the run directory."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    series = read_metrics(Path(run_dir) / CSV_NAME)
    names = [n for n in CURVES if n in series]
    out = Path(out) if out is not None else Path(run_dir) / "curves.png"
    columns = 3
    rows = max(1, math.ceil(len(names) / columns))
    fig, axes = plt.subplots(rows, columns, figsize=(4.2 * columns, 2.8 * rows), squeeze=False)
    for ax, name in zip(axes.flat, names):
        steps, values = (np.asarray(v) for v in series[name])
        ax.plot(steps, values, color="0.75", linewidth=0.8)
        if len(values) >= smooth > 1:
            kernel = np.ones(smooth) / smooth
            ax.plot(steps[smooth - 1:], np.convolve(values, kernel, mode="valid"), color="C0")
        ax.set_title(name, fontsize=9)
        ax.set_xlabel("env steps", fontsize=8)
        ax.tick_params(labelsize=7)
    for ax in list(axes.flat)[len(names):]:
        ax.axis("off")
    fig.tight_layout()
    tmp = out.with_name(out.name + ".tmp.png")
    fig.savefig(tmp, dpi=90)
    plt.close(fig)
    os.replace(tmp, out)
    return out
