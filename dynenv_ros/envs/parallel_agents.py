"""What both PettingZoo environments (``driving_v0``, ``robocup_v0``) do alike with their agents: look up an
agent's spaces and check a step's actions before anything moves, so that the two refuse the same mistakes with
the same messages."""
from __future__ import annotations

from collections.abc import Collection, Sequence
from typing import Any

from gymnasium import spaces


class AgentSpaces:
    """``observation_space``/``action_space`` by agent name, refusing unknown names. Mixed into an env that sets
    ``possible_agents``, ``_index`` (name → index) and ``_observation_spaces``/``_action_spaces`` (name → space)."""
    possible_agents: list[str]
    _index: dict[str, int]
    _observation_spaces: dict[str, spaces.Space]
    _action_spaces: dict[str, spaces.Space]

    def observation_space(self, agent: str) -> spaces.Space:
        return self._observation_spaces[self._known(agent)]

    def action_space(self, agent: str) -> spaces.Space:
        return self._action_spaces[self._known(agent)]

    def _known(self, agent: str) -> str:
        if agent not in self._index:
            raise ValueError(f"unknown agent {agent!r}; agents are {', '.join(self.possible_agents)}")
        return agent


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
