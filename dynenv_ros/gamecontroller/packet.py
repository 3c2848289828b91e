"""The RoboCup SPL GameController's UDP packets, ROS-free: RoboCupGameControlData ("RGme", sent to the robots)
and RoboCupGameControlReturnData ("RGrt", the robots' answer).

Written from the documented C struct of the current GameController (GameController3's
``game_controller_msgs/headers/RoboCupGameControlData.h``, struct version 18, return version 4; docs/interfaces.md,
"GameController"). Both structs are packed without padding and every multi-byte field is little-endian, as the
GameController writes them. Struct version 15 (2023) has the same layout; only the meaning of a few values grew
(``STATE_STANDBY``, ``KICKING_TEAM_NONE``, penalty 11), so ``encode_game_control_data(..., version=15)`` serves
readers that accept 15 only, such as ros-sports ``game_controller_spl`` 4.0.0.

Bad input gets a ``PacketError`` whose ``reason`` names the problem in one word (``length``, ``header``,
``version``, ``player_number``, ``fallen``, ``not_finite``, ``out_of_range``), so a node can count refusals by
reason and keep serving.
"""
from __future__ import annotations

import math
import struct
from dataclasses import dataclass, field

GAMECONTROLLER_DATA_PORT = 3838
GAMECONTROLLER_RETURN_PORT = 3939
GAMECONTROLLER_STRUCT_HEADER = b"RGme"
GAMECONTROLLER_STRUCT_VERSION = 18
# Versions with this layout that the encoder and decoder accept (15: the 2023 GameController).
SUPPORTED_STRUCT_VERSIONS = (15, 18)
GAMECONTROLLER_RETURN_STRUCT_HEADER = b"RGrt"
GAMECONTROLLER_RETURN_STRUCT_VERSION = 4
MAX_NUM_PLAYERS = 20

COMPETITION_PHASE_ROUNDROBIN, COMPETITION_PHASE_PLAYOFF = 0, 1
COMPETITION_TYPE_NORMAL, COMPETITION_TYPE_MOST_PASSES = 0, 1
GAME_PHASE_NORMAL, GAME_PHASE_PENALTYSHOOT, GAME_PHASE_OVERTIME, GAME_PHASE_TIMEOUT = 0, 1, 2, 3
STATE_INITIAL, STATE_READY, STATE_SET, STATE_PLAYING, STATE_FINISHED, STATE_STANDBY = 0, 1, 2, 3, 4, 5
SET_PLAY_NONE, SET_PLAY_GOAL_KICK, SET_PLAY_PUSHING_FREE_KICK, SET_PLAY_CORNER_KICK, SET_PLAY_KICK_IN, \
    SET_PLAY_PENALTY_KICK = 0, 1, 2, 3, 4, 5
KICKING_TEAM_NONE = 255
TEAM_BLUE, TEAM_RED = 0, 1          # team colours; 2 … 9: yellow, black, white, green, orange, purple, brown, gray

PENALTY_NONE = 0
PENALTY_SPL_ILLEGAL_BALL_CONTACT = 1
PENALTY_SPL_PLAYER_PUSHING = 2
PENALTY_SPL_ILLEGAL_MOTION_IN_SET = 3
PENALTY_SPL_INACTIVE_PLAYER = 4
PENALTY_SPL_ILLEGAL_POSITION = 5
PENALTY_SPL_LEAVING_THE_FIELD = 6
PENALTY_SPL_REQUEST_FOR_PICKUP = 7
PENALTY_SPL_LOCAL_GAME_STUCK = 8
PENALTY_SPL_ILLEGAL_POSITION_IN_SET = 9
PENALTY_SPL_PLAYER_STANCE = 10
PENALTY_SPL_ILLEGAL_MOTION_IN_STANDBY = 11
PENALTY_SUBSTITUTE = 14
PENALTY_MANUAL = 15

# Field lists (little-endian, no padding): header[4], version, packetNumber, playersPerTeam, competitionPhase,
# competitionType, gamePhase, state, setPlay, firstHalf, kickingTeam, secsRemaining, secondaryTime; then per team
# teamNumber, fieldPlayerColour, goalkeeperColour, goalkeeper, score, penaltyShot, singleShots, messageBudget and
# MAX_NUM_PLAYERS × (penalty, secsTillUnpenalised).
_GAME_HEAD = struct.Struct("<4s10Bhh")
_TEAM = struct.Struct("<6BHH" + "2B" * MAX_NUM_PLAYERS)
GAMECONTROLLER_STRUCT_SIZE = _GAME_HEAD.size + 2 * _TEAM.size            # 118 bytes
# header[4], version, playerNum, teamNum, fallen, pose[3] (x mm, y mm, theta rad), ballAge s, ball[2] (mm).
_RETURN = struct.Struct("<4s4B3ff2f")
GAMECONTROLLER_RETURN_STRUCT_SIZE = _RETURN.size                         # 32 bytes


class PacketError(ValueError):
    """A packet (or a value to encode) the GameController protocol does not allow; ``reason`` is one word."""

    def __init__(self, reason: str, message: str) -> None:
        super().__init__(f"{reason}: {message}")
        self.reason = reason


@dataclass(frozen=True)
class RobotInfo:
    penalty: int = PENALTY_NONE
    secs_till_unpenalised: int = 0


@dataclass(frozen=True)
class TeamInfo:
    team_number: int
    field_player_colour: int = TEAM_BLUE
    goalkeeper_colour: int = TEAM_BLUE
    goalkeeper: int = 1                  # player number (1 … MAX_NUM_PLAYERS)
    score: int = 0
    penalty_shot: int = 0
    single_shots: int = 0
    message_budget: int = 1200
    players: tuple[RobotInfo, ...] = field(default_factory=lambda: (RobotInfo(),) * MAX_NUM_PLAYERS)


@dataclass(frozen=True)
class GameControlData:
    """One RoboCupGameControlData packet's content (header and version are the encoder's business)."""
    teams: tuple[TeamInfo, TeamInfo]
    packet_number: int = 0
    players_per_team: int = 5
    competition_phase: int = COMPETITION_PHASE_ROUNDROBIN
    competition_type: int = COMPETITION_TYPE_NORMAL
    game_phase: int = GAME_PHASE_NORMAL
    state: int = STATE_INITIAL
    set_play: int = SET_PLAY_NONE
    first_half: bool = True
    kicking_team: int = KICKING_TEAM_NONE
    secs_remaining: int = 0
    secondary_time: int = 0
    version: int = GAMECONTROLLER_STRUCT_VERSION


@dataclass(frozen=True)
class ReturnData:
    """One RoboCupGameControlReturnData packet: who sends it and what it believes (GameController units: mm)."""
    player_num: int
    team_num: int
    fallen: bool
    pose: tuple[float, float, float] = (0.0, 0.0, 0.0)     # x mm, y mm, theta rad in the field (own attack +x)
    ball_age: float = -1.0                                 # s since the ball was seen, -1 never
    ball: tuple[float, float] = (0.0, 0.0)                 # mm, relative to the robot


def _check_int(name: str, value: int, low: int, high: int) -> int:
    if isinstance(value, bool):
        value = int(value)
    if not isinstance(value, int) or not low <= value <= high:
        raise PacketError("out_of_range", f"{name} = {value!r} is not an integer in [{low}, {high}]")
    return value


def encode_game_control_data(data: GameControlData) -> bytes:
    """The 118-byte RGme packet for ``data`` (its ``version``: 18, or 15 for readers of the 2023 struct)."""
    if data.version not in SUPPORTED_STRUCT_VERSIONS:
        raise PacketError("version", f"struct version {data.version} is not one of {SUPPORTED_STRUCT_VERSIONS}")
    if len(data.teams) != 2:
        raise PacketError("out_of_range", f"a packet holds exactly 2 teams, got {len(data.teams)}")
    u8 = [("packet_number", data.packet_number), ("players_per_team", data.players_per_team),
          ("competition_phase", data.competition_phase), ("competition_type", data.competition_type),
          ("game_phase", data.game_phase), ("state", data.state), ("set_play", data.set_play),
          ("first_half", int(bool(data.first_half))), ("kicking_team", data.kicking_team)]
    head = [_check_int(n, v, 0, 255) for n, v in u8]
    if data.players_per_team > MAX_NUM_PLAYERS:
        raise PacketError("out_of_range", f"players_per_team {data.players_per_team} > {MAX_NUM_PLAYERS}")
    times = [_check_int(n, v, -2**15, 2**15 - 1) for n, v in (("secs_remaining", data.secs_remaining),
                                                                ("secondary_time", data.secondary_time))]
    out = bytearray(_GAME_HEAD.pack(GAMECONTROLLER_STRUCT_HEADER, data.version, *head, *times))
    for t, team in enumerate(data.teams):
        if len(team.players) != MAX_NUM_PLAYERS:
            raise PacketError("out_of_range", f"teams[{t}] has {len(team.players)} players; the packet has "
                              f"exactly {MAX_NUM_PLAYERS} slots")
        values = [_check_int(f"teams[{t}].{n}", getattr(team, n), 0, 255)
                  for n in ("team_number", "field_player_colour", "goalkeeper_colour", "goalkeeper", "score",
                            "penalty_shot")]
        values += [_check_int(f"teams[{t}].{n}", getattr(team, n), 0, 65535)
                   for n in ("single_shots", "message_budget")]
        for p, player in enumerate(team.players):
            values += [_check_int(f"teams[{t}].players[{p}].penalty", player.penalty, 0, 255),
                       _check_int(f"teams[{t}].players[{p}].secs_till_unpenalised", player.secs_till_unpenalised,
                                  0, 255)]
        out += _TEAM.pack(*values)
    return bytes(out)


def decode_game_control_data(packet: bytes) -> GameControlData:
    """An RGme packet (struct version 15 or 18) back to its content; refuses a wrong length, header or version."""
    if len(packet) != GAMECONTROLLER_STRUCT_SIZE:
        raise PacketError("length", f"RoboCupGameControlData is {GAMECONTROLLER_STRUCT_SIZE} bytes, got "
                          f"{len(packet)}")
    header, version, *head = _GAME_HEAD.unpack_from(packet, 0)
    if header != GAMECONTROLLER_STRUCT_HEADER:
        raise PacketError("header", f"expected {GAMECONTROLLER_STRUCT_HEADER!r}, got {header!r}")
    if version not in SUPPORTED_STRUCT_VERSIONS:
        raise PacketError("version", f"struct version {version} is not one of {SUPPORTED_STRUCT_VERSIONS}")
    (packet_number, players_per_team, competition_phase, competition_type, game_phase, state, set_play,
     first_half, kicking_team, secs_remaining, secondary_time) = head
    teams = []
    for t in range(2):
        v = _TEAM.unpack_from(packet, _GAME_HEAD.size + t * _TEAM.size)
        players = tuple(RobotInfo(v[8 + 2 * p], v[9 + 2 * p]) for p in range(MAX_NUM_PLAYERS))
        teams.append(TeamInfo(team_number=v[0], field_player_colour=v[1], goalkeeper_colour=v[2], goalkeeper=v[3],
                              score=v[4], penalty_shot=v[5], single_shots=v[6], message_budget=v[7],
                              players=players))
    return GameControlData(teams=(teams[0], teams[1]), packet_number=packet_number,
                           players_per_team=players_per_team, competition_phase=competition_phase,
                           competition_type=competition_type, game_phase=game_phase, state=state, set_play=set_play,
                           first_half=bool(first_half), kicking_team=kicking_team, secs_remaining=secs_remaining,
                           secondary_time=secondary_time, version=version)


def encode_return_data(data: ReturnData) -> bytes:
    """The 32-byte RGrt packet a robot sends back (for tests and for emulated robots)."""
    _check_int("player_num", data.player_num, 1, MAX_NUM_PLAYERS)
    _check_int("team_num", data.team_num, 0, 255)
    floats = (*data.pose, data.ball_age, *data.ball)
    if len(data.pose) != 3 or len(data.ball) != 2:
        raise PacketError("out_of_range", "pose has 3 components and ball 2")
    if not all(math.isfinite(f) for f in floats):
        raise PacketError("not_finite", f"pose, ball_age and ball must be finite: {floats}")
    return _RETURN.pack(GAMECONTROLLER_RETURN_STRUCT_HEADER, GAMECONTROLLER_RETURN_STRUCT_VERSION, data.player_num,
                        data.team_num, int(bool(data.fallen)), *floats)


def decode_return_data(packet: bytes) -> ReturnData:
    """A robot's RGrt packet; refuses a wrong length, header or version, a player number outside 1 … 20, a
    ``fallen`` other than 0 or 1, and a pose, ball age or ball that is not finite."""
    if len(packet) != GAMECONTROLLER_RETURN_STRUCT_SIZE:
        raise PacketError("length", f"RoboCupGameControlReturnData is {GAMECONTROLLER_RETURN_STRUCT_SIZE} bytes, "
                          f"got {len(packet)}")
    header, version, player_num, team_num, fallen, px, py, pt, ball_age, bx, by = _RETURN.unpack(packet)
    if header != GAMECONTROLLER_RETURN_STRUCT_HEADER:
        raise PacketError("header", f"expected {GAMECONTROLLER_RETURN_STRUCT_HEADER!r}, got {header!r}")
    if version != GAMECONTROLLER_RETURN_STRUCT_VERSION:
        raise PacketError("version", f"return struct version {version}, expected "
                          f"{GAMECONTROLLER_RETURN_STRUCT_VERSION}")
    if not 1 <= player_num <= MAX_NUM_PLAYERS:
        raise PacketError("player_number", f"player number {player_num} is outside 1 … {MAX_NUM_PLAYERS}")
    if fallen > 1:
        raise PacketError("fallen", f"fallen is {fallen}, must be 0 or 1")
    if not all(math.isfinite(f) for f in (px, py, pt, ball_age, bx, by)):
        raise PacketError("not_finite", "pose, ball age and ball must be finite")
    return ReturnData(player_num=player_num, team_num=team_num, fallen=bool(fallen), pose=(px, py, pt),
                      ball_age=ball_age, ball=(bx, by))
