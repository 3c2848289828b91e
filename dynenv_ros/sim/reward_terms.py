"""Rewards as separate named terms per agent, so learners and logs can weigh and inspect each one."""
from __future__ import annotations

from collections.abc import Iterable
from enum import IntEnum

import numpy as np


class RewardTerm(IntEnum):
    """The terms of StepFeedback.msg: task outcome, rule violations, shaping, and what the agent got to see."""
    PRIMARY = 0
    RULE = 1
    AUXILIARY = 2
    OBSERVATION = 3


class RewardLedger:
    """Accumulates each term for each agent over one motion period."""

    def __init__(self, n_agents: int) -> None:
        self.values = np.zeros((len(RewardTerm), n_agents))

    def add(self, term: RewardTerm, agent: int, value: float) -> None:
        self.values[term, agent] += value

    def add_many(self, term: RewardTerm, agents: Iterable[int], value: float) -> None:
        self.values[term, list(agents)] += value

    def clear(self) -> None:
        self.values.fill(0.0)

    def total(self) -> np.ndarray:
        """Per-agent sum of all terms."""
        total: np.ndarray = self.values.sum(axis=0)
        return total

    def as_dicts(self) -> list[dict[str, float]]:
        """One {term name: value} dict per agent, for infos and logs."""
        return [{term.name.lower(): float(self.values[term, a]) for term in RewardTerm}
                for a in range(self.values.shape[1])]
