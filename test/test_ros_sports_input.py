"""A team stack's ros-sports messages back into what the policy reads (issue 41): soccer_vision_3d arrays to detection
rows in the camera frame (perception/soccer_vision_3d.py), per-class messages grouped into frames by stamp
(ros/frame_parts.py), RCGCD15 to the game values (gamecontroller/robot_view.py); bad input refused with a reason."""
from __future__ import annotations

import math
from collections import Counter

import numpy as np
import pytest
from game_controller_spl_interfaces.msg import RCGCD15
from soccer_vision_3d_msgs.msg import Ball, BallArray, MarkingArray, MarkingIntersection, Robot, RobotArray
from std_msgs.msg import Header

from dynenv_ros.core.object_classes import ObjectClass, Subtype
from dynenv_ros.gamecontroller import packet as gc
from dynenv_ros.gamecontroller.robot_view import Refused, robot_view
from dynenv_ros.perception import soccer_vision_3d as sv
from dynenv_ros.ros.frame_parts import FrameParts
from dynenv_ros.ros.ros_sports_conversion import soccer_vision_messages
from detection_rows import rows

MS = 1_000_000



FRAME = rows(
    dict(class_id=ObjectClass.BALL, x=2.0, y=0.5, size_x=0.1, size_y=0.1, confidence=0.8),
    dict(class_id=ObjectClass.ROBOT, x=1.5, y=-0.4, yaw=2.0, size_x=0.3, size_y=0.3, confidence=0.9, team=-1,
         fallen=True),
    dict(class_id=ObjectClass.ROBOT, x=3.0, y=1.0, yaw=np.nan, size_x=0.3, size_y=0.3, confidence=0.4, team=1,
         penalized=True),
    dict(class_id=ObjectClass.GOALPOST, x=4.0, y=-1.2, size_x=0.1, size_y=0.1, confidence=0.7),
    # a line seen from (1, -1) (the nearer end) to (1, 2): its point nearest the camera (1, 0), 3 m, 5 cm wide
    dict(class_id=ObjectClass.FIELD_LINE, x=1.0, y=0.0, yaw=-math.pi / 2, size_x=3.0, size_y=0.05,
         line_start_x=1.0, line_start_y=-1.0, line_end_x=1.0, line_end_y=2.0, confidence=0.6),
    dict(class_id=ObjectClass.LINE_CROSSING, x=2.5, y=-2.0, subtype=Subtype.CROSSING_T, size_x=0.1, size_y=0.1,
         confidence=0.5),
    dict(class_id=ObjectClass.CENTER_CIRCLE, x=3.0, y=0.0, size_x=1.5, size_y=1.5, confidence=0.9),
    dict(class_id=ObjectClass.PENALTY_CROSS, x=2.0, y=2.0, size_x=0.1, size_y=0.1, confidence=0.3))
KINDS = ("balls", "robots", "goalposts", "markings")


@pytest.mark.parametrize("head_yaw", [0.0, 0.6, -1.2])
def test_the_simulators_messages_come_back_as_its_detections(head_yaw):
    """Camera frame → soccer_vision_3d (the simulator's mapping) → back: every field that maps survives."""
    messages = soccer_vision_messages(sv.soccer_vision_3d(FRAME, head_yaw), Header(frame_id="team_a_0/base_link"))
    back = sv.camera_rows(np.concatenate([sv.detection_rows(k, m) for k, m in zip(KINDS, messages)]), head_yaw)
    assert list(back["class_id"]) == [ObjectClass.BALL, ObjectClass.ROBOT, ObjectClass.ROBOT, ObjectClass.GOALPOST,
                                      ObjectClass.FIELD_LINE, ObjectClass.LINE_CROSSING, ObjectClass.CENTER_CIRCLE,
                                      ObjectClass.PENALTY_CROSS]
    order = [0, 1, 2, 3, 4, 5, 6, 7]
    for field in ("x", "y", "size_x", "size_y", "confidence", "team", "subtype", "fallen", "penalized",
                  "line_start_x", "line_start_y", "line_end_x", "line_end_y"):
        assert np.allclose(back[field].astype(float), FRAME[order][field].astype(float), atol=1e-5), field
    assert math.isclose(back["yaw"][1], 2.0, abs_tol=1e-5) and np.isnan(back["yaw"][2])      # robots' headings
    assert abs(math.sin(back["yaw"][4] + math.pi / 2)) < 1e-5      # a line's direction, modulo π (±π/2 alike)


def test_a_stacks_own_conventions_read_as_the_emulation_reports():
    """A ball on the ground (z 0), a confidence the detector does not give (-1), a crossing of unknown shape."""
    balls = BallArray(balls=[Ball()])
    balls.balls[0].center.x, balls.balls[0].confidence.confidence = 1.0, -1.0
    (ball,) = sv.detection_rows("balls", balls)
    assert (ball["size_x"], ball["confidence"]) == pytest.approx((0.1, 1.0))
    markings = MarkingArray(intersections=[MarkingIntersection(num_rays=5)])
    markings.intersections[0].confidence.confidence = 0.5
    assert sv.detection_rows("markings", markings)["subtype"][0] == Subtype.NONE


def _robot(**attributes) -> RobotArray:
    robot = Robot()
    robot.bb.center.orientation.w = 1.0
    robot.confidence.confidence = 0.5
    for key, value in attributes.items():
        setattr(robot.attributes, key, value)
    return RobotArray(robots=[robot])


@pytest.mark.parametrize("kind, message, reason", [
    ("robots", _robot(team=3), "enum"),
    ("robots", _robot(state=9), "enum"),
    ("balls", BallArray(balls=[Ball()] * (sv.MAX_PER_MESSAGE + 1)), "too_many"),
])
def test_messages_the_policy_cannot_read_are_refused_with_the_reason(kind, message, reason):
    with pytest.raises(sv.MessageRefused) as refused:
        sv.detection_rows(kind, message)
    assert refused.value.reason == reason


@pytest.mark.parametrize("value, reason", [(math.nan, "not_finite"), (1.5, "confidence"), (-0.5, "confidence")])
def test_a_nan_position_or_a_confidence_outside_0_to_1_is_refused(value, reason):
    balls = BallArray(balls=[Ball()])
    if reason == "not_finite":
        balls.balls[0].center.y = value
    else:
        balls.balls[0].confidence.confidence = value
    with pytest.raises(sv.MessageRefused, match=reason):
        sv.detection_rows("balls", balls)


def test_class_messages_of_one_stamp_make_one_frame():
    counts: Counter[str] = Counter()
    parts = FrameParts(KINDS, tolerance_ns=40 * MS, wait_ns=30 * MS, counts=counts)
    assert parts.add("balls", 100 * MS, 0, "b") == []
    assert parts.add("robots", 102 * MS, 1 * MS, "r") == []        # 2 ms off: the same frame
    assert parts.add("balls", 100 * MS, 2 * MS, "again") == []     # a second balls message: kept the first
    assert parts.add("goalposts", 100 * MS, 3 * MS, "g") == []
    (frame,) = parts.add("markings", 100 * MS, 4 * MS, "m")
    assert (frame.stamp_ns, frame.parts) == (100 * MS, {"balls": "b", "robots": "r", "goalposts": "g",
                                                          "markings": "m"})
    assert parts.add("robots", 100 * MS, 5 * MS, "late") == []      # its frame went on already
    assert (counts["parts_duplicate"], counts["parts_late"], counts["frames_incomplete"]) == (1, 1, 0)


def test_a_lost_class_message_closes_its_frame_when_that_stream_moved_on_or_the_wait_ran_out():
    counts: Counter[str] = Counter()
    parts = FrameParts(KINDS, tolerance_ns=40 * MS, wait_ns=30 * MS, counts=counts)
    for kind in ("balls", "robots", "goalposts"):          # frame 100 ms: its markings are lost
        parts.add(kind, 100 * MS, 0, kind)
    assert parts.add("markings", 200 * MS, 10 * MS, "m2") != []   # the markings stream is at 200 ms: 100 goes on
    assert counts["frames_incomplete"] == 1 and counts["parts_missing"] == 1
    (alone,) = parts.due(40 * MS)                                   # frame 200: only its markings came
    assert alone.stamp_ns == 200 * MS and list(alone.parts) == ["markings"]
    parts.add("balls", 300 * MS, 100 * MS, "b3")                  # nothing else of frame 300 comes
    assert parts.due(129 * MS) == []
    (frame,) = parts.due(130 * MS)
    assert frame.stamp_ns == 300 * MS and list(frame.parts) == ["balls"]


def _rcgcd(state=gc.STATE_PLAYING, set_play=gc.SET_PLAY_NONE, kicking=21, secondary=7, remaining=300):
    msg = RCGCD15(state=state, set_play=set_play, kicking_team=kicking, secondary_time=secondary,
                  secs_remaining=remaining, players_per_team=2)
    msg.teams[0].team_number, msg.teams[1].team_number = 21, 22
    msg.teams[1].players[1].penalty = gc.PENALTY_SPL_PLAYER_PUSHING
    return msg


def test_the_game_as_each_robot_reads_it():
    """Team 21's kick-off, 7 s until the ball is free, 300 s left; team 22's player 2 is penalized."""
    own = robot_view(_rcgcd(), team_number=21, player_number=1)
    assert (own.ball_owner, own.ball_owner_seconds, own.game_seconds_remaining, own.penalized) == (1, 7.0, 300.0,
                                                                                                  False)
    other = robot_view(_rcgcd(), team_number=22, player_number=2)
    assert (other.ball_owner, other.ball_owner_seconds, other.penalized) == (-1, 7.0, True)
    free = robot_view(_rcgcd(kicking=gc.KICKING_TEAM_NONE, secondary=0), 22, 1)
    assert (free.ball_owner, free.ball_owner_seconds) == (0, 0.0)
    kick_in = robot_view(_rcgcd(set_play=gc.SET_PLAY_KICK_IN, kicking=22, secondary=20), 21, 1)
    assert (kick_in.ball_owner, kick_in.ball_owner_seconds) == (-1, 20.0)


@pytest.mark.parametrize("change, reason", [
    (dict(state=9), "state"), (dict(set_play=6), "set_play"), (dict(kicking=99), "kicking_team")])
def test_a_gamecontroller_message_with_unknown_values_is_refused(change, reason):
    with pytest.raises(Refused) as refused:
        robot_view(_rcgcd(**change), 21, 1)
    assert refused.value.reason == reason
    with pytest.raises(Refused, match="team"):
        robot_view(_rcgcd(), 5, 1)                 # not a team of this game
    msg = _rcgcd()
    msg.teams[0].players[0].penalty = 200
    with pytest.raises(Refused, match="penalty"):
        robot_view(msg, 21, 1)
