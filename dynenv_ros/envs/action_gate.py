"""Which actions a served game runs: the simulator node's screen, check and bookkeeping of every Action. ROS-free:
messages are read by attribute (``dynenv_msgs/Action``'s fields), so the ROS adapter (``nodes/sim_node.py``) and its
action inbox (``ros/action_inbox.py``) only carry them here.

An action runs if it names its own robot, passes the session's checks (episode, period, duplicates, field ranges:
``session.ActionSession``) and — with secrets (``security/action_auth.py``, issue 27) — carries its team's MAC for
a (robot, episode, period) not acted on before. The screen reads only, so the inbox's thread may call it; ``admit``
changes the session and runs on the owner's thread. Each robot's accepted action is remembered by its digest, so
the feedback of the period it ran names it (``StepFeedback.action_digest``). Refusals are counted in the session's
counters and summarised for the log once per diagnostics period: logging each one cost ~30x the check itself, so a
flood of bad actions starved the node's services.
"""
from __future__ import annotations

from collections import Counter
from collections.abc import Callable, Sequence
from typing import Any

from dynenv_ros.envs.session import ActionSession, refusal_key
from dynenv_ros.security.action_auth import GameSecrets, ReplayGuard, action_digest, check_action

# Digests kept for periods that ran and whose feedback has not gone out yet (real time: it follows within a period).
EXECUTED_DEPTH = 8


class ActionGate:
    """Screens and admits one game's actions (module docstring). ``topics``: each robot's fully qualified action
    topic, which its MAC and digest are bound to (the namespace is part of a robot's identity); ``labels``: the same
    topics as a refusal names them."""

    def __init__(self, session: ActionSession, names: Sequence[str], topics: Sequence[str], labels: Sequence[str],
                 secrets: GameSecrets | None, fields: Callable[[Any], tuple[Any, ...]]) -> None:
        self.session, self.names, self.topics, self.secrets = session, list(names), list(topics), secrets
        self.labels = list(labels)
        self.fields = fields        # the scenario's fields of an Action (``Scenario.action_fields``)
        self.replay_guard = ReplayGuard()
        self.accepted: dict[int, bytes] = {}                           # robot -> digest, for the period collected
        self.executed: dict[tuple[int, int], dict[int, bytes]] = {}   # (episode, period) run -> digests
        self.refused_since_log: Counter[str] = Counter()              # refusals not yet summarised in the log
        self.last_refusal = ""

    def screen(self, robot: int, msg: Any) -> tuple[str, str]:
        """On the inbox thread: ("", "") for an action the session may accept now, else its counter key and
        reason. Reads the session only; ``admit`` (on the owner's thread) re-checks what passes."""
        if msg.robot_id != robot:
            return "rejected_unknown_robot", (f"unknown_robot: robot_id {msg.robot_id} on "
                                              f"{self.labels[robot]} (expected {robot})")
        if self.secrets is not None:
            problem = self._authentication_problem(robot, msg)
            if problem:
                return refusal_key(problem), f"{self.names[robot]}: {problem}"
        reason = self.session.check(msg.robot_id, msg.episode_id, msg.motion_period, *self.fields(msg))
        return (refusal_key(reason), f"{self.names[robot]}: {reason}") if reason else ("", "")

    def _authentication_problem(self, robot: int, msg: Any) -> str:
        """Why ``msg`` is not its robot's team's own, fresh action: "" (it is), ``mac_missing``, ``mac_invalid``
        (forged, altered, another team's secret or another topic's) or ``replayed`` (its nonce was used)."""
        assert self.secrets is not None
        problem = check_action(msg, self.topics[robot], self.secrets.for_agent(self.names[robot]))
        if problem:
            return f"{problem}: episode {msg.episode_id} period {msg.motion_period}"
        if self.replay_guard.used((msg.robot_id, msg.episode_id, msg.motion_period)):
            return f"replayed: episode {msg.episode_id} period {msg.motion_period} was acted on already"
        return ""

    def admit(self, robot: int, msg: Any) -> bool:
        """On the owner's thread: submit an action that passed the screen (the period may have moved on since);
        False when the session refused it (counted)."""
        accepted, reason = self.session.submit(msg.robot_id, msg.episode_id, msg.motion_period, *self.fields(msg))
        if not accepted:
            self.count_refusals(Counter({refusal_key(reason): 1}), f"{self.names[robot]}: {reason}", counted=True)
            return False
        self.accepted[robot] = action_digest(msg, self.topics[robot])
        if self.secrets is not None:
            self.replay_guard.use((msg.robot_id, msg.episode_id, msg.motion_period))
        return True

    def count_refusals(self, refused: Counter[str], last: str, counted: bool = False) -> None:
        """Count refusals (``counted``: the session has counted them already) and keep them for the log's summary."""
        if not counted:
            self.session.counts.update(refused)
        for key, n in refused.items():
            if key.startswith("rejected_"):
                self.refused_since_log[key[len("rejected_"):]] += n
                self.last_refusal = last

    def refusal_summary(self) -> str:
        """The log line of the refusals since the last one ("" when none), and start counting afresh."""
        if not self.refused_since_log:
            return ""
        summary = ", ".join(f"{n} {k}" for k, n in sorted(self.refused_since_log.items()))
        self.refused_since_log.clear()
        return f"actions refused since the last report: {summary}; last: {self.last_refusal}"

    def period_runs(self) -> dict[int, bytes]:
        """The digests of the actions the period about to run was collected with; collecting starts afresh."""
        executed, self.accepted = self.accepted, {}
        return executed

    def period_ran(self, episode: int, period: int, executed: dict[int, bytes]) -> None:
        self.executed[(episode, period)] = executed
        while len(self.executed) > EXECUTED_DEPTH:
            del self.executed[next(iter(self.executed))]

    def digests(self, episode: int, period: int) -> dict[int, bytes]:
        """Robot -> digest of the actions a period ran (empty for period 0 or a period run without actions)."""
        return self.executed.pop((episode, period), {})

    def clear(self) -> None:
        """A new episode: nothing collected or run yet."""
        self.accepted.clear()
        self.executed.clear()


__all__ = ["ActionGate", "EXECUTED_DEPTH"]
