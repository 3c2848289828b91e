"""What one robot's policy reads from the GameController (issue 41): the inverse of ``game_state``, ROS-free.

A team's stack receives the GameController's packet as ``game_controller_spl_interfaces/RCGCD15`` on ``gc/data``;
the policy needs the three game values of ``DetectionArray`` (docs/interfaces.md) and the robot's own penalty:

- ``ball_owner`` relative to the robot's team: +1 when ``kicking_team`` is its team's number, −1 when it is the
  other team's, 0 when it is ``KICKING_TEAM_NONE`` — during ``STATE_PLAYING`` only while a set play runs or
  ``secondary_time`` counts down (a kick-off's ownership), as the simulator's game announces it (``game_state``);
- ``ball_owner_seconds``: ``secondary_time`` while the ball is owned, else 0;
- ``game_seconds_remaining``: ``secs_remaining`` (never below 0);
- ``penalized``: the robot's slot (``players[player_number − 1]`` of its team) holds any penalty, a substitute
  included (a robot that is not in the game does not play).

The packet's times are whole seconds, so these are too. A message that is not a GameController packet is refused
with a one-word reason (``malformed``, ``state``, ``set_play``, ``team``, ``kicking_team``, ``penalty``,
``players_per_team``), and the caller counts it and keeps its previous values.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from dynenv_ros.gamecontroller import packet as gc

STATES = (gc.STATE_INITIAL, gc.STATE_READY, gc.STATE_SET, gc.STATE_PLAYING, gc.STATE_FINISHED, gc.STATE_STANDBY)
SET_PLAYS = (gc.SET_PLAY_NONE, gc.SET_PLAY_GOAL_KICK, gc.SET_PLAY_PUSHING_FREE_KICK, gc.SET_PLAY_CORNER_KICK,
             gc.SET_PLAY_KICK_IN, gc.SET_PLAY_PENALTY_KICK)
KNOWN_PENALTIES = frozenset(range(0, 12)) | {gc.PENALTY_SUBSTITUTE, gc.PENALTY_MANUAL}


class Refused(ValueError):
    """A message the GameController would not send; ``reason`` is one word."""

    def __init__(self, reason: str, message: str) -> None:
        super().__init__(f"{reason}: {message}")
        self.reason = reason


@dataclass(frozen=True)
class RobotView:
    """The game as one robot's policy reads it."""
    ball_owner: int                 # +1 own team, −1 opponents, 0 free
    ball_owner_seconds: float       # s
    game_seconds_remaining: float   # s
    penalized: bool
    state: int


def robot_view(msg: Any, team_number: int, player_number: int) -> RobotView:
    """The view of player ``player_number`` (1 … 20) of team ``team_number`` from an RCGCD message (or a
    ``packet.GameControlData``: read by attribute); ``Refused`` with the reason otherwise."""
    try:
        state, set_play = int(msg.state), int(msg.set_play)
        kicking, secondary, remaining = int(msg.kicking_team), int(msg.secondary_time), int(msg.secs_remaining)
        teams = list(msg.teams)
        players_per_team = int(msg.players_per_team)
        numbers = [int(t.team_number) for t in teams]
    except (AttributeError, TypeError, ValueError) as error:
        raise Refused("malformed", f"not a GameController message: {error}") from None
    if state not in STATES:
        raise Refused("state", f"unknown state {state}")
    if set_play not in SET_PLAYS:
        raise Refused("set_play", f"unknown set play {set_play}")
    if not 0 <= players_per_team <= gc.MAX_NUM_PLAYERS:
        raise Refused("players_per_team", f"players_per_team {players_per_team} > {gc.MAX_NUM_PLAYERS}")
    if len(teams) != 2 or team_number not in numbers:
        raise Refused("team", f"team {team_number} is not in the message (teams {numbers})")
    own = teams[numbers.index(team_number)]
    other_number = numbers[1 - numbers.index(team_number)]
    if kicking not in (team_number, other_number, gc.KICKING_TEAM_NONE):
        raise Refused("kicking_team", f"kicking team {kicking} is neither team nor {gc.KICKING_TEAM_NONE}")
    players = list(own.players)
    if not 1 <= player_number <= len(players):
        raise Refused("team", f"player {player_number} has no slot (the team has {len(players)})")
    penalty = int(players[player_number - 1].penalty)
    if penalty not in KNOWN_PENALTIES:
        raise Refused("penalty", f"unknown penalty {penalty} of player {player_number}")
    owned = kicking != gc.KICKING_TEAM_NONE and state == gc.STATE_PLAYING and (
        set_play != gc.SET_PLAY_NONE or secondary > 0)
    owner = 0 if not owned else (1 if kicking == team_number else -1)
    return RobotView(ball_owner=owner, ball_owner_seconds=float(max(0, secondary)) if owned else 0.0,
                     game_seconds_remaining=float(max(0, remaining)), penalized=penalty != gc.PENALTY_NONE,
                     state=state)


__all__ = ["Refused", "RobotView", "robot_view"]
