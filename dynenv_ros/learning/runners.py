"""``make_trainer``: the trainer a config's ``runner`` names, ``Trainer`` (sync) or ``AsyncTrainer`` (async).

Its own module because ``async_trainer`` builds on ``trainer``: here, above both, the choice imports neither module
back (no import cycle, .importlinter). ``dynenv-train`` (``train_cli``) and ``dynenv-sweep`` call it.
"""
from __future__ import annotations

from pathlib import Path

from dynenv_ros.learning.config import TrainConfig
from dynenv_ros.learning.trainer import Trainer


def make_trainer(cfg: TrainConfig, run_dir: str | Path, resume: bool = False, progress: bool = True) -> Trainer:
    """The trainer of ``cfg.runner``: ``Trainer`` (sync) or ``async_trainer.AsyncTrainer``."""
    if cfg.runner == "async":
        from dynenv_ros.learning.async_trainer import AsyncTrainer      # the worker pool only when asked for
        return AsyncTrainer(cfg, run_dir, resume=resume, progress=progress)
    return Trainer(cfg, run_dir, resume=resume, progress=progress)
