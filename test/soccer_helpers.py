"""Small builders for soccer world tests: a world with chosen settings and robots parked out of the way."""
from __future__ import annotations

from typing import Any

import numpy as np

from dynenv_ros.soccer.actions import SoccerAction
from dynenv_ros.soccer.config import SoccerConfig
from dynenv_ros.soccer.world import SoccerWorld

IDLE = SoccerAction()


def make_world(players_per_team: int = 1, seed: int = 0, falls: dict[str, Any] | None = None,
               **settings: Any) -> SoccerWorld:
    """A world without random falls (unless ``falls`` says otherwise), all robots parked, ball free at the centre."""
    config = SoccerConfig.from_mapping({"players_per_team": players_per_team,
                                        "falls": {"enabled": False, **(falls or {})}, **settings})
    world = SoccerWorld(config, seed=seed)
    park_all(world)
    world.place_ball(0.0, 0.0)
    world.set_ball_owner(0, 0.0)
    return world


def park_all(world: SoccerWorld) -> None:
    """Robots spread along y = ±2.5 and away from the ball, facing their attack direction."""
    for robot in world.robots:
        x = -robot.team * (1.0 + 0.6 * robot.slot)
        world.place_robot(robot.index, x, 2.5 * robot.team, 0.0 if robot.team > 0 else 3.141592653589793)


def idle_steps(world: SoccerWorld, periods: int, overrides: dict[int, SoccerAction] | None = None) -> list:
    """Step with every robot idle except ``overrides``; return all events seen."""
    events = []
    for _ in range(periods):
        actions = [(overrides or {}).get(i, IDLE) for i in range(world.n_robots)]
        events += world.step(actions).events
    return events


def kinds(events: list, kind: str) -> list:
    return [e for e in events if e.kind == kind]


def assert_identical(a: Any, b: Any) -> None:
    """Nested dicts / sequences / arrays equal bit for bit (NaN included), dtypes and shapes too."""
    if isinstance(a, dict):
        assert sorted(a) == sorted(b)
        for key in a:
            assert_identical(a[key], b[key])
    elif isinstance(a, (tuple, list)):
        assert len(a) == len(b)
        for x, y in zip(a, b):
            assert_identical(x, y)
    elif a is None:
        assert b is None
    else:
        a, b = np.asarray(a), np.asarray(b)
        assert a.dtype == b.dtype and a.shape == b.shape
        assert a.tobytes() == b.tobytes()
