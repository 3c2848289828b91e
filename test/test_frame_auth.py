"""Authenticated frames' core (issue 43 item 4, ``security/frame_auth.py``): the simulator's bytes of a frame (from
its numpy records) equal a receiver's (from the message it got), every field is covered, and the gate hands on a
frame only once its tag came, refusing the rest by reason."""
from __future__ import annotations

import math

import numpy as np
import pytest
from rclpy.serialization import deserialize_message

from dynenv_msgs.msg import DetectionArray, WorldState
from dynenv_ros.envs.soccer_session import SoccerSession
from dynenv_ros.perception.params import load_preset
from dynenv_ros.ros import conversions as cv
from dynenv_ros.ros.cdr import detection_array_cdr
from dynenv_ros.security.frame_auth import (FrameGate, detection_array_bytes, detection_rows_bytes, tag_frame,
                                            world_state_bytes)
from dynenv_ros.soccer.config import SoccerConfig

SECRET = bytes(range(32))
TOPIC = "/team_a_0/detections"
FIELDS = dict(stamp_sec=12, stamp_nanosec=345_000_000, frame_id="team_a_0/camera", robot_id=0, episode_id=3,
              motion_period=41, frame_index=4, frames_per_period=5, head_yaw=-0.7512345, fallen=False,
              penalized=True, kicking=True, ball_owner=-1, ball_owner_seconds=7.25, game_seconds_remaining=93.1)


def _output():
    session = SoccerSession(SoccerConfig(players_per_team=2), load_preset("realistic", noise_magnitude=3.0), seed=2)
    return session.step()


def _received(rows) -> DetectionArray:
    """What a receiver gets: the simulator's fast CDR bytes, deserialised."""
    return deserialize_message(detection_array_cdr(rows, **FIELDS), DetectionArray)


@pytest.mark.parametrize("count", [0, 1, 7, 40])
def test_the_simulators_bytes_of_a_frame_are_the_receivers(count):
    rows = np.concatenate([r.detections for f in _output().frames for r in f.robots])[:count]
    assert len(rows) == count
    msg = _received(rows)
    assert detection_rows_bytes(rows, TOPIC, **FIELDS) == detection_array_bytes(msg, TOPIC)


def test_every_field_of_a_frame_and_its_topic_are_covered():
    rows = np.concatenate([r.detections for f in _output().frames for r in f.robots])[:3]
    genuine = detection_array_bytes(_received(rows), TOPIC)
    assert detection_array_bytes(_received(rows), "/team_a_1/detections") != genuine
    changes = [("header.stamp.nanosec", 1), ("header.frame_id", "x"), ("robot_id", 1), ("episode_id", 4),
               ("motion_period", 42), ("frame_index", 3), ("frames_per_period", 6), ("head_yaw", 0.1),
               ("self_fallen", True), ("self_penalized", False), ("self_kicking", False), ("ball_owner", 1),
               ("ball_owner_seconds", 1.0), ("game_seconds_remaining", 1.0)]
    for detection_field in ("class_id", "position.x", "position.y", "position.z", "yaw", "size_x", "size_y",
                            "confidence", "team", "subtype", "fallen", "penalized", "line_start.z", "line_end.x",
                            "sighting"):
        changes.append((f"detections.1.{detection_field}", None))
    for path, value in changes:
        msg = _received(rows)
        *parents, last = path.split(".")
        target = msg
        for part in parents:
            target = target[int(part)] if part.isdigit() else getattr(target, part)
        old = getattr(target, last)
        new = value if value is not None else (not old if isinstance(old, bool) else
                                               (old + 1 if isinstance(old, int) else 0.25 if old != 0.25 else 0.5))
        setattr(target, last, new)
        assert detection_array_bytes(msg, TOPIC) != genuine, path
    msg = _received(rows)
    msg.detections = msg.detections[:2]
    assert detection_array_bytes(msg, TOPIC) != genuine


def test_a_world_state_built_by_the_simulator_reads_back_to_the_same_bytes():
    from rclpy.serialization import serialize_message
    snapshot = _output().frames[-1].snapshot
    built = cv.world_state(snapshot, cv.Time(sec=3, nanosec=7))
    received = deserialize_message(serialize_message(built), WorldState)
    assert world_state_bytes(built, "/world_state") == world_state_bytes(received, "/world_state")
    assert math.isnan(received.objects[0].goal_x)              # NaN fields are covered, canonically
    received.objects[1].x += 1e-9
    assert world_state_bytes(received, "/world_state") != world_state_bytes(built, "/world_state")
    assert world_state_bytes(built, "/game_2/world_state") != world_state_bytes(built, "/world_state")


def test_the_gate_hands_on_a_frame_once_its_tag_came_in_either_order():
    gate = FrameGate(SECRET, wait_s=2.0)
    a, b = b"frame a", b"frame b"
    assert gate.frame("A", a, now_ns=0) == []                            # waits for its tag
    assert gate.tag(tag_frame(SECRET, a), now_ns=1_000) == ["A"]
    assert gate.tag(tag_frame(SECRET, b), now_ns=2_000) == []            # a tag first waits for its frame
    assert gate.frame("B", b, now_ns=3_000) == ["B"]
    assert gate.counts == {"frame_mac_missing": 0, "frame_replayed": 0, "tag_malformed": 0, "tag_unmatched": 0,
                           "frames_verified": 2}


def test_the_gate_refuses_forged_untagged_replayed_frames_and_bad_tags():
    gate = FrameGate(SECRET, wait_s=2.0, capacity=3)
    assert gate.frame("forged", b"forged", now_ns=0) == []
    assert gate.tag(tag_frame(b"another secret of 32 bytes......", b"forged"), now_ns=10) == []   # wrong key
    assert gate.tag(b"\x01" * 15, now_ns=20) == []
    assert gate.frame("genuine", b"genuine", 30) == [] and gate.tag(tag_frame(SECRET, b"genuine"), 40) == ["genuine"]
    assert gate.frame("again", b"genuine", now_ns=50) == []              # the genuine frame replayed
    assert gate.tag(tag_frame(SECRET, b"genuine"), now_ns=60) == []      # its tag replayed: nothing waits for it
    gate.expire(2_000_000_100)                                           # 2 s later: the forged frame's wait ends
    assert gate.counts == {"frame_mac_missing": 1, "frame_replayed": 1, "tag_malformed": 1, "tag_unmatched": 1,
                           "frames_verified": 1}
    assert gate.last_refusal.startswith("tag_unmatched") and gate.waiting == 0
    for k in range(5):                                                   # a flood: the oldest waiting are refused
        gate.frame(k, b"flood %d" % k, now_ns=3_000_000_000)
    assert gate.waiting == 3 and gate.counts["frame_mac_missing"] == 3


def test_a_tag_that_comes_after_the_wait_still_verifies_its_frame_and_the_others_expire():
    """A node too busy to read a tag within the wait (the train graph's stall under load): the tag is matched before
    anything expires, so its frame is used; an untagged frame that waited as long is still refused."""
    gate = FrameGate(SECRET, wait_s=2.0)
    assert gate.frame("late", b"late", now_ns=0) == [] and gate.frame("forged", b"forged", now_ns=0) == []
    assert gate.tag(tag_frame(SECRET, b"late"), now_ns=3_000_000_000) == ["late"]     # 3 s: still verifies
    assert gate.counts["frame_mac_missing"] == 1 and gate.waiting == 0               # the untagged one expired
    assert gate.tag(tag_frame(SECRET, b"first"), now_ns=4_000_000_000) == []         # a tag before its frame …
    assert gate.frame("first", b"first", now_ns=7_000_000_000) == ["first"]          # … 3 s later, still used
    # a batch of queued tags expires nothing until its end
    gate.frame("x", b"x", now_ns=8_000_000_000)
    assert gate.tag(b"\x02" * 16, now_ns=11_000_000_000, expire=False) == [] and gate.waiting == 1
    assert gate.tag(tag_frame(SECRET, b"x"), now_ns=11_000_000_000, expire=False) == ["x"]


def test_a_gate_needs_a_secret():
    with pytest.raises(ValueError, match="secret of >= 16 bytes"):
        FrameGate(b"")


def test_a_frame_waits_two_seconds_and_a_receiver_holds_1024_waiting():
    """docs/ros_graph.md, "Which frames count": by default a frame waits at most 2 s and 1,024 frames for its tag."""
    gate = FrameGate(SECRET)
    assert gate.frame("untagged", b"untagged", now_ns=0) == []
    gate.expire(1_999_000_000)
    assert gate.waiting == 1 and gate.counts["frame_mac_missing"] == 0          # still waiting at 1.999 s
    gate.expire(2_001_000_000)
    assert gate.waiting == 0 and gate.counts["frame_mac_missing"] == 1          # refused past 2 s
    for k in range(1024):
        gate.frame(k, b"flood %d" % k, now_ns=3_000_000_000)
    assert gate.waiting == 1024 and gate.counts["frame_mac_missing"] == 1
    gate.frame("one more", b"one more", now_ns=3_000_000_000)
    assert gate.waiting == 1024 and gate.counts["frame_mac_missing"] == 2       # the oldest pushed out
