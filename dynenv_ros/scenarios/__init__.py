"""The scenario registry (issue 40): one ``Scenario`` per world — soccer (``SOCCER``) and driving (``DRIVING``) —
owning what the layers above would otherwise decide with ``if driving`` branches: its names, its settings, its
session (world and perception), its observation layout, its action codec (the fields of ``dynenv_msgs/Action``,
the fallback and previous actions, sampling and scoring a policy's outputs, the checks a policy passes before it
acts). ``get_scenario(name)`` resolves any accepted spelling; docs/decisions.md ("A scenario registry") says why
the canonical names are ``soccer`` and ``driving`` and where the old spellings are still accepted. ROS-free.
"""
from dynenv_ros.scenarios.registry import DRIVING, SCENARIOS, SOCCER, Scenario, get_scenario, scenario_names, scenario_of

__all__ = ["DRIVING", "SCENARIOS", "SOCCER", "Scenario", "get_scenario", "scenario_names", "scenario_of"]
