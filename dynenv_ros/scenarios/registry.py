"""The registered scenarios and ``get_scenario``: every spelling a user, a file or a message may use resolves to
one of them, and an unknown one is refused with the choices."""
from __future__ import annotations

from dynenv_ros.scenarios.base import Scenario
from dynenv_ros.scenarios.driving import DrivingScenario
from dynenv_ros.scenarios.soccer import SoccerScenario

SOCCER: Scenario = SoccerScenario()
DRIVING: Scenario = DrivingScenario()
SCENARIOS: tuple[Scenario, ...] = (SOCCER, DRIVING)
_BY_NAME = {spelling: s for s in SCENARIOS for spelling in (s.name, s.parameter_value, *s.aliases)}
_BY_CODE = {s.world_code: s for s in SCENARIOS}


def scenario_names() -> list[str]:
    """Every accepted spelling, canonical names first."""
    return [s.name for s in SCENARIOS] + [n for n in _BY_NAME if n not in {s.name for s in SCENARIOS}]


def get_scenario(name: str | int | Scenario) -> Scenario:
    """The scenario a name (canonical or legacy), a ``WorldState.SCENARIO_*`` code, or a Scenario stands for;
    ValueError naming the choices otherwise."""
    if isinstance(name, Scenario):
        return name
    if isinstance(name, int) and not isinstance(name, bool):
        if name in _BY_CODE:
            return _BY_CODE[name]
        raise ValueError(f"unknown scenario code {name}; codes are {sorted(_BY_CODE)}")
    if isinstance(name, str) and name in _BY_NAME:
        return _BY_NAME[name]
    raise ValueError(f"unknown scenario {name!r}; choose one of {', '.join(repr(n) for n in scenario_names())}")


def scenario_of(agent: object) -> Scenario:
    """The scenario a ``DynEnvAgent`` (or a policy wrapping one) was built for: its ``scenario``, soccer where it has
    none (agents from before driving)."""
    return get_scenario(getattr(agent, "scenario", "soccer"))


__all__ = ["DRIVING", "SCENARIOS", "SOCCER", "Scenario", "get_scenario", "scenario_names", "scenario_of"]
