"""A game through ros-sports messages only (issue 41): the simulator publishing soccer_vision_3d_msgs, RCGCD15 and
joint states, a policy node with ``interfaces:=ros_sports`` answering with twists, kick requests and head commands,
and the motion emulator turning them into the simulator's actions. Every period runs the action the policy chose
(its own Action, moved aside to ``<robot>/policy_action``, is the reference); and the simulator's GameController on
UDP, decoded by a decoder written here from the published struct layout."""
from __future__ import annotations

import math
import socket
import struct

import pytest
from dynenv_msgs.msg import Action
from rclpy.parameter import Parameter

from dynenv_ros.nodes.motion_emulator import MotionEmulator
from dynenv_ros.nodes.sim_node import SimNode
from dynenv_ros.ros.qos import action_stream
from policy_node.policy_node import PolicyNode
from ros_harness import spin_until

SHIPPED = "policy_node/pretrained/policy.onnx"


def _params(**values):
    return [Parameter(k, value=v) for k, v in values.items()]


def test_a_game_through_ros_sports_messages_runs_every_action_the_policy_chose(make_node, executor):
    from pathlib import Path
    checkpoint = str(Path(__file__).resolve().parents[1] / SHIPPED)
    names = ("team_a_0", "team_b_0")
    policy = make_node(PolicyNode, parameter_overrides=_params(
        players_per_team=1, interfaces="ros_sports", checkpoint=checkpoint, greedy=True, frame_epoch=0.1,
        class_wait=0.5), cli_args=["--ros-args"] + [a for n in names for a in ("-r", f"{n}/action:={n}/policy_action")])
    emulator = make_node(MotionEmulator, parameter_overrides=_params(players_per_team=1))
    probe = make_node("probe")
    chosen: dict[str, list] = {n: [] for n in names}
    executed: dict[str, list] = {n: [] for n in names}
    for n in names:
        probe.create_subscription(Action, f"{n}/policy_action", chosen[n].append, action_stream())
        probe.create_subscription(Action, f"{n}/action", executed[n].append, action_stream())
    for node in (policy, emulator, probe):
        executor.add_node(node)
    spin_until(executor, lambda: all(policy.count_publishers(f"{n}/cmd_vel") for n in names), 10.0)
    spin_until(executor, lambda: False, 1.0)                       # the nodes' readers match one another
    sim = make_node(SimNode, parameter_overrides=_params(
        players_per_team=1, seed=5, ros_sports=True, publish_markers=False, episode_seconds=8.0, auto_reset=False,
        wait_for_subscribers=0, falls_enabled=False))
    executor.add_node(sim)
    assert spin_until(executor, lambda: sim.session.finished, 120.0), sim.diagnostics()
    spin_until(executor, lambda: False, 0.5)
    diagnostics = sim.diagnostics()
    periods = int(diagnostics["periods_run"])
    assert periods == 16
    assert int(diagnostics["accepted"]) == 2 * periods and int(diagnostics["missing"]) == 0
    assert not any(int(v) for k, v in diagnostics.items() if k.startswith("rejected_")), diagnostics
    assert emulator.counts["actions_answered"] == 2 * (periods - 1), dict(emulator.counts)   # period 1: initial
    for n in names:        # paired by the frame answered: the policy numbers periods on its own camera grid
        by_frame = {(a.header.stamp.sec, a.header.stamp.nanosec): a for a in chosen[n]}
        runs = [a for a in executed[n] if a.motion_period >= 2]
        assert len(runs) >= periods - 1
        for action in runs:
            mine = by_frame[(action.header.stamp.sec, action.header.stamp.nanosec)]
            assert (action.walk, action.turn, action.kick) == (mine.walk, mine.turn, mine.kick if not (
                mine.walk or mine.turn) else 0)
            assert action.head_yaw_delta == pytest.approx(mine.head_yaw_delta, abs=1e-6)
    counts = policy.diagnostics()
    assert int(counts["ros_sports_head_yaw_used"]) == int(counts["ros_sports_frames_passed"]) > 0
    assert int(counts["ros_sports_fallen_used"]) == int(counts["ros_sports_frames_passed"])    # the fall flags came
    assert counts.get("ros_sports_frames_incomplete", "0") == "0"


# -- the GameController on UDP, decoded from the published layout -------------------------------------------------
# RoboCupGameControlData (GameController3 v5, struct version 18; docs/interfaces.md): header char[4], version,
# packetNumber, playersPerTeam, competitionPhase, competitionType, gamePhase, state, setPlay, firstHalf, kickingTeam
# (uint8 each), secsRemaining, secondaryTime (int16), then two TeamInfo of teamNumber, fieldPlayerColour,
# goalkeeperColour, goalkeeper, score, penaltyShot (uint8), singleShots, messageBudget (uint16) and 20 × (penalty,
# secsTillUnpenalised) (uint8); packed, little-endian: 18 + 2 × 50 = 118 bytes.
def decode_rgme(packet: bytes) -> dict:
    assert len(packet) == 118
    head = packet[:18]
    out = {"header": head[:4], "version": head[4], "packet_number": head[5], "players_per_team": head[6],
           "state": head[10], "set_play": head[11], "first_half": head[12], "kicking_team": head[13],
           "secs_remaining": int.from_bytes(head[14:16], "little", signed=True),
           "secondary_time": int.from_bytes(head[16:18], "little", signed=True), "teams": []}
    for t in range(2):
        team = packet[18 + 50 * t: 18 + 50 * (t + 1)]
        out["teams"].append({"number": team[0], "score": team[4], "message_budget": team[8] | team[9] << 8,
                             "penalties": [team[10 + 2 * p] for p in range(20)]})
    return out


def rgrt(player: int, team: int, fallen: int, version: int = 4, values=(0.0,) * 6, extra: bytes = b"") -> bytes:
    """RoboCupGameControlReturnData: "RGrt", version 4, playerNum, teamNum, fallen (uint8), pose[3], ballAge, ball[2]
    (float32), little-endian, 32 bytes."""
    return b"RGrt" + bytes([version, player, team, fallen]) + struct.pack("<6f", *values) + extra


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_the_simulator_sends_the_gamecontroller_packet_and_reads_return_packets(make_node, executor):
    receiver = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    receiver.bind(("127.0.0.1", 0))
    receiver.settimeout(0.01)
    port, return_port = receiver.getsockname()[1], _free_port()
    sim = make_node(SimNode, parameter_overrides=_params(
        players_per_team=2, seed=1, publish_markers=False, wait_for_subscribers=0, gc_udp_port=port,
        gc_return_port=return_port, gc_team_number_a=12, gc_team_number_b=34, mode="realtime",
        real_time_factor=5.0))
    executor.add_node(sim)
    packets: list[bytes] = []

    def receive() -> bool:
        try:
            packets.append(receiver.recv(1024))
        except (TimeoutError, BlockingIOError):
            pass
        return len(packets) >= 3
    assert spin_until(executor, receive, 20.0)
    first = decode_rgme(packets[0])
    assert (first["header"], first["version"], first["players_per_team"], first["first_half"]) == (b"RGme", 18, 2, 1)
    assert [p["number"] for p in first["teams"]] == [12, 34]
    assert first["state"] == 3 and first["kicking_team"] == 12 and 0 < first["secondary_time"] <= 10
    assert first["teams"][0]["penalties"] == [0, 0] + [14] * 18 and first["teams"][0]["message_budget"] == 1200
    assert [decode_rgme(p)["packet_number"] for p in packets[:3]] == [first["packet_number"] + k for k in range(3)]
    assert 0 < first["secs_remaining"] <= 120
    sender = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    good = rgrt(1, 12, 0, values=(100.0, -200.0, 0.5, 1.0, 300.0, 0.0))
    bad = [rgrt(1, 12, 0, version=3), rgrt(0, 12, 0), rgrt(1, 12, 2), rgrt(1, 12, 0, values=(math.nan,) + (0.0,) * 5),
           rgrt(1, 12, 0, extra=b"x"), b"RGxx" + good[4:]]
    for packet in [good] + bad:
        sender.sendto(packet, ("127.0.0.1", return_port))
    assert spin_until(executor, lambda: sum(int(v) for k, v in sim.diagnostics().items()
                                            if k.startswith("gc_return_")) >= 7, 10.0), sim.diagnostics()
    counts = sim.diagnostics()
    assert int(counts["gc_return_accepted"]) == 1 and int(counts["gc_packets_sent"]) >= 3
    for reason in ("version", "player_number", "fallen", "not_finite", "length", "header"):
        assert counts[f"gc_return_refused_{reason}"] == "1", reason
    assert sim.outlet.robot_io.link.latest[(12, 1)].pose == pytest.approx((100.0, -200.0, 0.5))
    assert spin_until(executor, lambda: len(packets) >= 5 or receive(), 10.0)    # still serving
    sender.close()
    receiver.close()


@pytest.mark.parametrize("params, message", [({"gc_udp_port": 0}, "gc_udp_port"),
                                             ({"gc_udp_port": 3838, "gc_team_number_b": 1}, "distinct")])
def test_bad_gamecontroller_parameters_are_refused(make_node, params, message):
    from rclpy.exceptions import ParameterException
    with pytest.raises(ParameterException, match=message):
        make_node(SimNode, parameter_overrides=_params(players_per_team=1, wait_for_subscribers=0, **params))
