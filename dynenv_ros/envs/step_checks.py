"""Checks both PettingZoo environments (``driving_v0``, ``robocup_v0``) make on a step's actions before anything
moves, so that the two refuse the same mistakes with the same messages."""
from __future__ import annotations

from collections.abc import Collection, Sequence
from typing import Any


def check_step_actions(env_name: str, agents: Sequence[str], known: Collection[str], actions: Any) -> None:
    """RuntimeError if the episode is over (no live ``agents``); ValueError unless ``actions`` is a dict with only
    ``known`` agents and an action for every live one. The actions themselves are checked by the world."""
    if not agents:
        raise RuntimeError(f"{env_name}: the episode is over (or reset() was never called); call reset()")
    if not isinstance(actions, dict):
        raise ValueError(f"actions must be a dict agent -> action, got {type(actions).__name__}")
    for agent in actions:
        if agent not in known:
            raise ValueError(f"unknown agent {agent!r} in actions; agents are {', '.join(agents)}")
    missing = [a for a in agents if a not in actions]
    if missing:
        raise ValueError(f"no action for {', '.join(missing)}")
