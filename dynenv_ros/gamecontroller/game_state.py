"""The simulated soccer game as the SPL GameController would announce it (ROS-free).

The simulator's referee (``soccer/referee.py``) runs a simplified game: one half, a kick-off and set plays whose
ball ownership runs out, timed penalties. ``game_control_data`` says the same in the GameController's words
(docs/interfaces.md, "GameController"), so a team's stack reading ``gc/data`` or the UDP packet sees the simulated
game as it sees a real one:

- phase → state and set play: INITIAL → ``STATE_INITIAL``; KICKOFF and PLAYING → ``STATE_PLAYING`` (a kick-off is
  ``SET_PLAY_NONE`` with the kicking team and its ownership in ``secondary_time``, as the GameController shows the
  time until the ball is free); KICK_IN, GOAL_KICK, CORNER_KICK → ``STATE_PLAYING`` with that set play;
  FINISHED → ``STATE_FINISHED``;
- ``kicking_team``: the team number of the team owning the ball, ``KICKING_TEAM_NONE`` (255) when it is free;
- times in whole seconds rounded up, as the GameController rounds its timers;
- team A is ``teams[0]``, team B ``teams[1]``; robot ``k`` of a team is player ``k + 1``; slots past the team's
  size are ``PENALTY_SUBSTITUTE``, as the GameController marks players not in the game.
"""
from __future__ import annotations

import math
from collections.abc import Mapping

from dynenv_ros.core.object_classes import ObjectClass, ObjectStatus
from dynenv_ros.gamecontroller import packet as gc
from dynenv_ros.sim.ground_truth import WorldSnapshot
from dynenv_ros.soccer.config import is_soccer_world
from dynenv_ros.soccer.referee import Phase

_STATES = {Phase.INITIAL: (gc.STATE_INITIAL, gc.SET_PLAY_NONE), Phase.KICKOFF: (gc.STATE_PLAYING, gc.SET_PLAY_NONE),
           Phase.PLAYING: (gc.STATE_PLAYING, gc.SET_PLAY_NONE),
           Phase.KICK_IN: (gc.STATE_PLAYING, gc.SET_PLAY_KICK_IN),
           Phase.GOAL_KICK: (gc.STATE_PLAYING, gc.SET_PLAY_GOAL_KICK),
           Phase.CORNER_KICK: (gc.STATE_PLAYING, gc.SET_PLAY_CORNER_KICK),
           Phase.FINISHED: (gc.STATE_FINISHED, gc.SET_PLAY_NONE)}

# The simulator's penalty reasons (soccer/world.py, ``_penalize``) by the start of their text → the SPL penalty.
# Touching the ball in the opponents' free kick is a position offence in the SPL (the defenders must keep away).
PENALTY_REASONS = (("left the field", gc.PENALTY_SPL_LEAVING_THE_FIELD),
                   ("illegal defender", gc.PENALTY_SPL_ILLEGAL_POSITION),
                   ("touched the ball during the opponents' free kick", gc.PENALTY_SPL_ILLEGAL_POSITION),
                   ("pushing robot", gc.PENALTY_SPL_PLAYER_PUSHING),
                   ("fell ", gc.PENALTY_SPL_INACTIVE_PLAYER))


def penalty_code(reason: str) -> int:
    """The SPL penalty of a simulator penalty reason (an event's detail); ``PENALTY_MANUAL`` for one not known."""
    for prefix, code in PENALTY_REASONS:
        if reason.startswith(prefix):
            return code
    return gc.PENALTY_MANUAL


def whole_seconds(seconds: float, low: int, high: int) -> int:
    """Seconds rounded up (the GameController's rounding of a running timer), clamped to the field's range."""
    if not math.isfinite(seconds):
        raise ValueError(f"a time must be finite, got {seconds}")
    return max(low, min(high, math.ceil(seconds - 1e-9)))


def game_control_data(snapshot: WorldSnapshot, *, players_per_team: int, team_numbers: tuple[int, int],
                      packet_number: int = 0, penalties: Mapping[int, int] | None = None,
                      version: int = gc.GAMECONTROLLER_STRUCT_VERSION) -> gc.GameControlData:
    """The GameController's packet content for a soccer ``snapshot``.

    ``team_numbers``: (team A's, team B's) SPL team numbers, distinct, 1 … 254 (255 means no team).
    ``penalties``: robot id → SPL penalty code of a penalized robot (``penalty_code`` of its reason); a penalized
    robot missing from it gets ``PENALTY_MANUAL``. ``packet_number`` wraps at 256."""
    if not is_soccer_world(snapshot.scenario):
        raise ValueError("the GameController describes soccer only (WorldState.SCENARIO_SOCCER)")
    if not 1 <= players_per_team <= gc.MAX_NUM_PLAYERS:
        raise ValueError(f"players_per_team must be 1 … {gc.MAX_NUM_PLAYERS}, got {players_per_team}")
    a, b = team_numbers
    if not (1 <= a <= 254 and 1 <= b <= 254 and a != b):
        raise ValueError(f"team numbers must be two distinct numbers in 1 … 254, got {team_numbers}")
    try:
        phase = Phase(snapshot.phase)
    except ValueError:
        raise ValueError(f"unknown game phase {snapshot.phase}") from None
    state, set_play = _STATES[phase]
    penalties = penalties or {}
    owner = snapshot.ball_owner_team
    if owner not in (1, -1, 0):
        raise ValueError(f"ball_owner_team must be 1, -1 or 0, got {owner}")
    kicking_team = a if owner == 1 else b if owner == -1 else gc.KICKING_TEAM_NONE
    secondary = whole_seconds(snapshot.ball_owner_remaining, 0, 2**15 - 1) if owner != 0 else 0
    players: dict[int, list[gc.RobotInfo]] = {1: [], -1: []}
    for body in sorted((o for o in snapshot.objects if o.class_id == ObjectClass.ROBOT), key=lambda o: o.id):
        if body.team not in players:
            raise ValueError(f"robot {body.id} has team {body.team}; soccer robots are team 1 or -1")
        if body.status & ObjectStatus.PENALIZED:
            info = gc.RobotInfo(penalties.get(body.id, gc.PENALTY_MANUAL),
                                whole_seconds(body.penalty_remaining, 0, 255))
        else:
            info = gc.RobotInfo()
        players[body.team].append(info)
    teams = []
    for team, number, score in ((1, a, snapshot.score_team_a), (-1, b, snapshot.score_team_b)):
        if len(players[team]) != players_per_team:
            raise ValueError(f"team {'A' if team == 1 else 'B'} has {len(players[team])} robots in the snapshot, "
                             f"players_per_team is {players_per_team}")
        slots = players[team] + [gc.RobotInfo(gc.PENALTY_SUBSTITUTE, 0)] * (gc.MAX_NUM_PLAYERS - players_per_team)
        teams.append(gc.TeamInfo(team_number=number, field_player_colour=gc.TEAM_BLUE if team == 1 else gc.TEAM_RED,
                                 goalkeeper_colour=gc.TEAM_BLUE if team == 1 else gc.TEAM_RED, goalkeeper=1,
                                 score=min(255, score), players=tuple(slots)))
    return gc.GameControlData(teams=(teams[0], teams[1]), packet_number=packet_number % 256,
                              players_per_team=players_per_team, state=state, set_play=set_play, first_half=True,
                              kicking_team=kicking_team,
                              secs_remaining=whole_seconds(snapshot.time_remaining, 0, 2**15 - 1),
                              secondary_time=secondary, version=version)
