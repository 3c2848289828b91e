"""The SPL GameController's UDP packets (dynenv_ros/gamecontroller): what the encoder sends is read back by an
independent decoder written here from the published C struct (GameController3's RoboCupGameControlData.h, struct
version 18, return version 4), not by the project's code; malformed packets are refused with a reason."""
from __future__ import annotations

import math
import struct

import pytest

from dynenv_ros.core.object_classes import ObjectClass, ObjectStatus
from dynenv_ros.gamecontroller import packet as gc
from dynenv_ros.gamecontroller.game_state import game_control_data, penalty_code
from dynenv_ros.sim.ground_truth import BodyState, WorldSnapshot

# The published layout, field by field (little-endian, packed):
#   char header[4]; uint8 version, packetNumber, playersPerTeam, competitionPhase, competitionType, gamePhase,
#   state, setPlay, firstHalf, kickingTeam; int16 secsRemaining, secondaryTime; TeamInfo teams[2] where
#   TeamInfo = uint8 teamNumber, fieldPlayerColour, goalkeeperColour, goalkeeper, score, penaltyShot;
#   uint16 singleShots, messageBudget; RobotInfo players[20] = (uint8 penalty, uint8 secsTillUnpenalised).
GAME_FIELDS = ["header", "version", "packetNumber", "playersPerTeam", "competitionPhase", "competitionType",
               "gamePhase", "state", "setPlay", "firstHalf", "kickingTeam", "secsRemaining", "secondaryTime"]
TEAM_FIELDS = ["teamNumber", "fieldPlayerColour", "goalkeeperColour", "goalkeeper", "score", "penaltyShot",
               "singleShots", "messageBudget"]
GAME_FORMAT = "<4s" + "B" * 10 + "hh"
TEAM_FORMAT = "<" + "B" * 6 + "HH" + "BB" * 20
# char header[4]; uint8 version, playerNum, teamNum, fallen; float pose[3], ballAge, ball[2].
RETURN_FORMAT = "<4sBBBBffffff"


def independent_decode(packet: bytes) -> dict:
    assert struct.calcsize(GAME_FORMAT) + 2 * struct.calcsize(TEAM_FORMAT) == 118 == len(packet)
    head = dict(zip(GAME_FIELDS, struct.unpack_from(GAME_FORMAT, packet, 0)))
    head["teams"] = []
    for t in range(2):
        values = struct.unpack_from(TEAM_FORMAT, packet, 18 + 50 * t)
        team = dict(zip(TEAM_FIELDS, values[:8]))
        team["players"] = [(values[8 + 2 * p], values[9 + 2 * p]) for p in range(20)]
        head["teams"].append(team)
    return head


def robot(i: int, team: int, penalized: float = 0.0) -> BodyState:
    return BodyState(id=i, class_id=ObjectClass.ROBOT, team=team,
                     status=ObjectStatus.PENALIZED if penalized else ObjectStatus.NONE, penalty_remaining=penalized)


def kick_in_snapshot() -> WorldSnapshot:
    """2 v 2, 83.2 s left, team B owns a kick-in for 12.4 s more; team A's robot 1 penalized (pushing, 17.3 s
    left), team B's robot 2 penalized (reason unknown to the caller, 0.5 s left); score 2 : 1."""
    objects = (robot(0, 1), robot(1, 1, 17.3), robot(2, -1, 0.5), robot(3, -1),
               BodyState(id=4, class_id=ObjectClass.BALL, x=1.0))
    return WorldSnapshot(scenario=0, episode_id=3, tick=3680, tick_period=0.01, game_time=36.8, time_remaining=83.2,
                         phase=3, ball_owner_team=-1, ball_owner_remaining=12.4, score_team_a=2, score_team_b=1,
                         objects=objects)


def test_the_simulated_game_encodes_to_the_published_layout():
    data = game_control_data(kick_in_snapshot(), players_per_team=2, team_numbers=(12, 34), packet_number=300,
                             penalties={1: penalty_code("pushing robot 2")})
    packet = gc.encode_game_control_data(data)
    d = independent_decode(packet)
    assert (d["header"], d["version"], d["packetNumber"], d["playersPerTeam"]) == (b"RGme", 18, 300 % 256, 2)
    assert (d["competitionPhase"], d["competitionType"], d["gamePhase"]) == (0, 0, 0)
    assert (d["state"], d["setPlay"], d["firstHalf"], d["kickingTeam"]) == (3, 4, 1, 34)   # PLAYING, KICK_IN, B
    assert (d["secsRemaining"], d["secondaryTime"]) == (84, 13)                          # rounded up
    a, b = d["teams"]
    assert (a["teamNumber"], a["score"], b["teamNumber"], b["score"]) == (12, 2, 34, 1)
    assert (a["fieldPlayerColour"], b["fieldPlayerColour"], a["goalkeeper"], a["messageBudget"]) == (0, 1, 1, 1200)
    assert a["players"][:2] == [(0, 0), (2, 18)]          # PENALTY_SPL_PLAYER_PUSHING, 18 s
    assert b["players"][:2] == [(15, 1), (0, 0)]          # PENALTY_MANUAL (no reason given), 1 s
    assert a["players"][2:] == b["players"][2:] == [(14, 0)] * 18     # PENALTY_SUBSTITUTE: not in the game


def test_every_field_of_a_hand_built_packet_reaches_its_offset():
    players = tuple(gc.RobotInfo(p % 16, 200 + p) for p in range(20))
    teams = (gc.TeamInfo(team_number=5, field_player_colour=2, goalkeeper_colour=3, goalkeeper=4, score=6,
                         penalty_shot=7, single_shots=0xBEEF, message_budget=1234, players=players),
             gc.TeamInfo(team_number=9, players=(gc.RobotInfo(),) * 20))
    data = gc.GameControlData(teams=teams, packet_number=17, players_per_team=7, competition_phase=1,
                              competition_type=1, game_phase=2, state=5, set_play=5, first_half=False,
                              kicking_team=255, secs_remaining=-3, secondary_time=-32768, version=15)
    d = independent_decode(gc.encode_game_control_data(data))
    assert [d[f] for f in GAME_FIELDS] == [b"RGme", 15, 17, 7, 1, 1, 2, 5, 5, 0, 255, -3, -32768]
    assert [d["teams"][0][f] for f in TEAM_FIELDS] == [5, 2, 3, 4, 6, 7, 0xBEEF, 1234]
    assert d["teams"][0]["players"] == [(p % 16, 200 + p) for p in range(20)]
    assert gc.decode_game_control_data(gc.encode_game_control_data(data)) == data


@pytest.mark.parametrize("change, reason", [
    (dict(secs_remaining=40000), "out_of_range"), (dict(kicking_team=256), "out_of_range"),
    (dict(players_per_team=21), "out_of_range"), (dict(version=16), "version")])
def test_values_the_packet_cannot_hold_are_refused_with_a_reason(change, reason):
    teams = (gc.TeamInfo(team_number=1), gc.TeamInfo(team_number=2))
    data = gc.GameControlData(teams=teams, **change)
    with pytest.raises(gc.PacketError) as error:
        gc.encode_game_control_data(data)
    assert error.value.reason == reason


def return_packet(header=b"RGrt", version=4, player=3, team=34, fallen=1, pose=(1500.0, -250.0, 0.5),
                  ball_age=2.25, ball=(800.0, 100.0)) -> bytes:
    return struct.pack(RETURN_FORMAT, header, version, player, team, fallen, *pose, ball_age, *ball)


def test_a_return_packet_built_from_the_published_layout_decodes():
    assert struct.calcsize(RETURN_FORMAT) == 32
    data = gc.decode_return_data(return_packet())
    assert data == gc.ReturnData(player_num=3, team_num=34, fallen=True, pose=(1500.0, -250.0, 0.5), ball_age=2.25,
                                 ball=(800.0, 100.0))
    assert gc.encode_return_data(data) == return_packet()


@pytest.mark.parametrize("packet, reason", [
    (return_packet(version=3), "version"),
    (return_packet(header=b"RGme"), "header"),
    (return_packet()[:31], "length"),
    (return_packet() + b"\0", "length"),
    (b"", "length"),
    (return_packet(player=0), "player_number"),
    (return_packet(player=21), "player_number"),
    (return_packet(fallen=2), "fallen"),
    (return_packet(pose=(math.nan, 0.0, 0.0)), "not_finite"),
    (return_packet(ball_age=math.inf), "not_finite")])
def test_malformed_return_packets_are_refused_with_a_reason(packet, reason):
    with pytest.raises(gc.PacketError) as error:
        gc.decode_return_data(packet)
    assert error.value.reason == reason
    assert str(error.value).startswith(reason + ": ")


@pytest.mark.parametrize("mutate, reason", [
    (lambda p: p[:4] + bytes([14]) + p[5:], "version"),
    (lambda p: b"RGrt" + p[4:], "header"),
    (lambda p: p[:-1], "length"),
    (lambda p: p + bytes(4), "length")])
def test_malformed_game_packets_are_refused_with_a_reason(mutate, reason):
    good = gc.encode_game_control_data(gc.GameControlData(teams=(gc.TeamInfo(team_number=1),
                                                                 gc.TeamInfo(team_number=2))))
    with pytest.raises(gc.PacketError) as error:
        gc.decode_game_control_data(mutate(good))
    assert error.value.reason == reason
