"""What every scenario world offers the environments, nodes and renderer: the seam where driving plugs in.

A scenario owns a ``PhysicsWorld``, its ``Rates`` and one seeded ``numpy.random.Generator``; ``step`` advances one
motion period and calls ``on_frame(k)`` at each vision instant so perception can look at the world mid-period.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable, Protocol, Sequence

import numpy as np

from dynenv_ros.sim.ground_truth import WorldSnapshot

FrameCallback = Callable[[int], None]


@dataclass(frozen=True)
class GameEvent:
    """Something the rules saw, for logs, infos and tests (e.g. 'fall', 'penalty', 'goal', 'out', 'crash')."""
    kind: str
    tick: int
    robot: int | None = None
    team: int = 0
    detail: str = ""


@dataclass
class PeriodResult:
    rewards: np.ndarray                    # (len(RewardTerm), n_agents)
    terminated: bool
    truncated: bool
    events: list[GameEvent] = field(default_factory=list)


class ScenarioWorld(Protocol):
    scenario: int                           # WorldState.SCENARIO_*
    episode_id: int
    tick: int
    rng: np.random.Generator

    def reset(self, seed: int | None = None) -> None: ...

    def step(self, actions: Sequence[Any], on_frame: FrameCallback | None = None,
             names: Sequence[str] | None = None) -> PeriodResult: ...

    def snapshot(self) -> WorldSnapshot: ...
