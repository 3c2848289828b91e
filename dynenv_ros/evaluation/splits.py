"""Named, disjoint seed ranges for evaluation, so that no choice is ever made on the games that give the final word.

- ``train``: 0 – 9,999. Free for anything: debugging, curves, quick looks. (Training runs seed their own worlds from
  ``SeedSequence(run seed)``, a different stream; these are evaluation seeds.)
- ``validation``: 10,000 – 19,999. Every choice (checkpoint, setting, greedy or sampled, when to stop) is made here.
- ``test``: 20,000 – 29,999. The final word only; every evaluation on it is appended to the test ledger
  (``evaluation.ledger``) by dynenv-eval itself.

Seeds 0–104, used as "held-out" before these splits existed, fall in ``train``: they were looked at too often.
"""
from __future__ import annotations

from typing import Sequence

SPLITS: dict[str, range] = {
    "train": range(0, 10_000),
    "validation": range(10_000, 20_000),
    "test": range(20_000, 30_000),
}


def split_seeds(split: str, count: int) -> list[int]:
    """The first ``count`` seeds of ``split``: a fixed set, so two policies evaluated on a split meet the same games."""
    if split not in SPLITS:
        raise ValueError(f"unknown split {split!r}: one of {', '.join(SPLITS)}")
    seeds = SPLITS[split]
    if not 1 <= count <= len(seeds):
        raise ValueError(f"--num-seeds must be in 1..{len(seeds)}, got {count}")
    return list(seeds[:count])


def check_in_split(split: str, seeds: Sequence[int]) -> None:
    """ValueError naming the first seed outside ``split``'s range."""
    if split not in SPLITS:
        raise ValueError(f"unknown split {split!r}: one of {', '.join(SPLITS)}")
    seeds_range = SPLITS[split]
    for seed in seeds:
        if seed not in seeds_range:
            raise ValueError(f"seed {seed} is not in split {split!r} ({seeds_range.start}..{seeds_range.stop - 1})")


def split_of(seeds: Sequence[int]) -> str | None:
    """The split every one of ``seeds`` lies in, or None when they straddle splits (or lie past them)."""
    for name, seeds_range in SPLITS.items():
        if seeds and all(s in seeds_range for s in seeds):
            return name
    return None
