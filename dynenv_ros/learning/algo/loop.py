"""The one training loop: pull experience from a source, learn from it, count it, tell the source, record it.

CleanRL's collect → update → log, with where the experience comes from left to an ``ExperienceSource``
(``experience``): this process's worlds (``sampling.in_process``), rollout workers in processes or Ray actors
(``distributed.pool_source``), the trainer node's messages (``messages.message_trainer``) and recorded bags
(``messages.bags``). ``learn`` is the algorithm's step (``ppo.update`` on the experience's batch, with whatever
the runner sets first); what a runner does around it (logs, checkpoints, the best policy, a progress bar) is its
``record``.
"""
from __future__ import annotations

import math
import time
from typing import Callable

from dynenv_ros.learning.algo.experience import Experience, ExperienceSource, Progress

Learn = Callable[[Experience], dict[str, float]]
# after each update: the experience, the update's scalars, the seconds spent waiting for the experience and learning
Record = Callable[[Experience, dict[str, float], float, float], None]


def learn_from(experience: Experience, learn: Learn, progress: Progress, source: ExperienceSource
               ) -> dict[str, float]:
    """One step of the loop on experience already in hand: the update, counted, and the source told."""
    stats = learn(experience)
    progress.env_steps += experience.env_steps
    progress.updates += 1
    progress.episodes += len(experience.finished)
    source.learned(progress)
    return stats


def train(source: ExperienceSource, learn: Learn, progress: Progress, record: Record | None = None,
          until: Callable[[Progress], bool] = lambda progress: True, deadline: float = math.inf) -> None:
    """Learn from ``source`` while ``until(progress)`` holds and ``deadline`` (``time.perf_counter``'s clock) has
    not passed, or until the source gives nothing more."""
    while until(progress) and time.perf_counter() < deadline:
        started = time.perf_counter()
        experience = source.next(progress, deadline)
        if experience is None:
            return
        learning = time.perf_counter()
        stats = learn_from(experience, learn, progress, source)
        if record is not None:
            record(experience, stats, learning - started, time.perf_counter() - learning)
