"""The nodes' side of authenticated actions (``security.action_auth``): one read-only parameter, ``secrets_dir``, the
same in every node that sends or reads Actions and StepFeedback, and the tagging of outgoing Actions.

``secrets_dir`` names a directory holding the secrets a node needs (``team_a.secret``, ``team_b.secret``,
``cars.secret``, ``simulator.secret``; docs/ros_graph.md, "Who may act"); empty (the default, local simulation)
switches authentication off. A missing or unsafe secret stops the node at start with a one-line parameter error.
"""
from __future__ import annotations

from collections.abc import Iterable
from typing import Any

from rclpy.exceptions import ParameterException
from rclpy.node import Node

from dynenv_ros.ros.parameters import declare_str
from dynenv_ros.security.action_auth import GameSecrets, SecretError, load_game_secrets, tag_action

SECRETS_PARAMETER = "secrets_dir"


def declare_secrets_dir(node: Node, who: str) -> str:
    """Declare ``secrets_dir`` (read-only); ``who``: which secrets this node reads from it, for ``--help``."""
    return declare_str(node, SECRETS_PARAMETER, "", f"Directory of the game's shared secrets for authenticated "
                       f"actions ({who}; made with dynenv-keys team-secret DIR/<name>.secret); empty: "
                       "authentication off (local simulation).", read_only=True)


def load_secrets(directory: str, agents: Iterable[str], simulator: bool) -> GameSecrets | None:
    """The secrets of ``agents``' teams (and the simulator's) from ``directory``; None when it is empty. A bad
    secret is a ParameterException naming ``secrets_dir``."""
    if not directory:
        return None
    try:
        return load_game_secrets(directory, agents, simulator)
    except SecretError as error:
        raise ParameterException(str(error), [SECRETS_PARAMETER]) from None


def secrets_for(node: Node, agents: Iterable[str], simulator: bool = False) -> GameSecrets | None:
    """Declare ``secrets_dir`` and load what ``agents`` (and, if asked, the simulator's tag) need."""
    agents = list(agents)
    who = "the team secrets of the robots it acts for" if not simulator else "team secrets and simulator.secret"
    return load_secrets(declare_secrets_dir(node, who), agents, simulator)


class ActionTagger:
    """Tags each outgoing Action with its agent's team secret, bound to the topic it is published on; does nothing
    when authentication is off (``secrets`` None)."""

    def __init__(self, secrets: GameSecrets | None) -> None:
        self.secrets = secrets
        self._topics: dict[int, str] = {}

    def __call__(self, agent: str, msg: Any, publisher: Any) -> None:
        if self.secrets is None:
            return
        topic = self._topics.get(id(publisher))
        if topic is None:
            topic = self._topics[id(publisher)] = publisher.topic_name
        msg.mac = tag_action(msg, topic, self.secrets.for_agent(agent))


def action_tagger(node: Node, agents: Iterable[str]) -> ActionTagger:
    """For a policy node: declare ``secrets_dir``, load the team secrets of ``agents`` and return their tagger."""
    return ActionTagger(secrets_for(node, agents))
