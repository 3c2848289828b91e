"""A robot's emulated detections as soccer_vision_3d_msgs records (perception/soccer_vision_3d.py): turned from the
camera frame into the body frame by the head's yaw, classes to message types, team and state to the attribute
codes, confidences kept; bad rows refused."""
from __future__ import annotations

import math

import pytest

from dynenv_ros.core.object_classes import ObjectClass, Subtype
from dynenv_ros.perception import soccer_vision_3d as sv
from dynenv_ros.perception.detections import empty
from detection_rows import rows



def close(a, b) -> bool:
    return all(math.isclose(x, y, abs_tol=1e-6) for x, y in zip(a, b))


def test_positions_turn_by_the_head_yaw_into_the_body_frame():
    """Head turned 90° left: what the camera sees 2 m ahead lies 2 m to the body's left."""
    frame = sv.soccer_vision_3d(rows(dict(class_id=ObjectClass.BALL, x=2.0, y=0.0, size_x=0.1, size_y=0.1,
                                          confidence=0.8)), head_yaw=math.pi / 2)
    (ball,) = frame.balls
    assert close((ball.x, ball.y, ball.z, ball.confidence), (0.0, 2.0, 0.05, 0.8))
    frame = sv.soccer_vision_3d(rows(dict(class_id=ObjectClass.BALL, x=1.0, y=1.0, size_x=0.1, confidence=0.5)),
                                head_yaw=-math.pi / 4)
    assert close((frame.balls[0].x, frame.balls[0].y), (math.sqrt(2), 0.0))


def test_robots_carry_team_state_facing_and_a_box_standing_on_the_ground():
    frame = sv.soccer_vision_3d(rows(
        # an opponent 2 m ahead facing the observer (heading π in the camera frame), fallen
        dict(class_id=ObjectClass.ROBOT, x=2.0, y=0.0, yaw=math.pi, size_x=0.3, size_y=0.2, confidence=0.9,
             team=-1, fallen=True),
        # a team mate 1 m to the left, facing away (heading π/2: along the line of sight), penalized
        dict(class_id=ObjectClass.ROBOT, x=0.0, y=1.0, yaw=math.pi / 2, size_x=0.3, size_y=0.2, confidence=0.6,
             team=1, penalized=True),
        # unknown team, heading unknown (NaN), standing
        dict(class_id=ObjectClass.ROBOT, x=1.0, y=-1.0, size_x=0.3, size_y=0.2, confidence=0.4, team=0),
        # 1 m ahead, facing to the observer's left (+y)
        dict(class_id=ObjectClass.ROBOT, x=1.0, y=0.0, yaw=math.pi / 2, size_x=0.3, size_y=0.2, confidence=0.3,
             team=1)), head_yaw=0.0)
    a, b, c, d = frame.robots
    assert (a.team, a.state, a.facing, a.player_number) == (sv.TEAM_OPPONENT, sv.STATE_FALLEN, sv.FACING_THIS_WAY, 0)
    assert close((a.bb.x, a.bb.y, a.bb.z, a.bb.size_x, a.bb.size_y, a.bb.size_z), (2.0, 0.0, 0.287, 0.3, 0.2, 0.574))
    assert math.isclose(abs(a.bb.yaw), math.pi, abs_tol=1e-6) and math.isclose(a.confidence, 0.9, abs_tol=1e-6)
    assert (b.team, b.state, b.facing) == (sv.TEAM_OWN, sv.STATE_INACTIVE, sv.FACING_AWAY)
    assert (c.team, c.state, c.facing, c.bb.yaw) == (sv.TEAM_UNKNOWN, sv.STATE_STANDING, sv.FACING_UNKNOWN, 0.0)
    assert d.facing == sv.FACING_LEFT
    # The head's yaw turns the heading too: head 90° left, a robot straight ahead in the camera facing +x of the
    # camera, lies at the body's left facing +y: away from the observer.
    (e,) = sv.soccer_vision_3d(rows(dict(class_id=ObjectClass.ROBOT, x=1.0, yaw=0.0, size_x=0.3, size_y=0.3,
                                         confidence=1.0)), head_yaw=math.pi / 2).robots
    assert close((e.bb.x, e.bb.y, e.bb.yaw), (0.0, 1.0, math.pi / 2)) and e.facing == sv.FACING_AWAY


def test_posts_and_markings():
    frame = sv.soccer_vision_3d(rows(
        dict(class_id=ObjectClass.GOALPOST, x=4.0, y=0.8, size_x=0.1, size_y=0.1, confidence=0.7),
        dict(class_id=ObjectClass.FIELD_LINE, x=1.0, y=0.0, line_start_x=1.0, line_start_y=-1.0, line_end_x=1.0,
             line_end_y=2.0, confidence=0.5),
        dict(class_id=ObjectClass.LINE_CROSSING, x=3.0, y=1.0, subtype=Subtype.CROSSING_T, confidence=0.55),
        dict(class_id=ObjectClass.LINE_CROSSING, x=3.0, y=-1.0, subtype=Subtype.CROSSING_L, confidence=0.55),
        dict(class_id=ObjectClass.LINE_CROSSING, x=3.0, y=-2.0, subtype=Subtype.CROSSING_X, confidence=0.55),
        dict(class_id=ObjectClass.CENTER_CIRCLE, x=2.0, y=0.5, size_x=1.5, size_y=1.5, confidence=0.65),
        dict(class_id=ObjectClass.PENALTY_CROSS, x=1.5, y=0.0, size_x=0.1, size_y=0.1, confidence=0.45),
        dict(class_id=ObjectClass.UNKNOWN, x=1.0, y=0.0, confidence=0.2)), head_yaw=math.pi)
    (post,) = frame.goalposts
    assert close((post.bb.x, post.bb.y, post.bb.z, post.bb.size_z), (-4.0, -0.8, 0.4, 0.8))
    assert (post.side, post.team) == (sv.SIDE_UNKNOWN, sv.TEAM_UNKNOWN)
    (segment,) = frame.segments
    assert close(segment.start + segment.end, (-1.0, 1.0, -1.0, -2.0))
    assert [i.num_rays for i in frame.intersections] == [3, 2, 4]
    assert close((frame.intersections[0].x, frame.intersections[0].y), (-3.0, -1.0))
    assert [(round(e.diameter, 6), round(e.confidence, 6)) for e in frame.ellipses] == [(1.5, 0.65), (0.1, 0.45)]
    assert close((frame.ellipses[0].x, frame.ellipses[0].y), (-2.0, -0.5))
    assert frame.unmapped == 1 and not frame.balls and not frame.robots


def test_an_empty_frame_gives_empty_arrays():
    frame = sv.soccer_vision_3d(empty(0), head_yaw=0.3)
    assert frame == sv.SoccerVision3D()


@pytest.mark.parametrize("row, head_yaw, message", [
    (dict(class_id=ObjectClass.BALL, x=1.0, confidence=1.5), 0.0, "confidence must be in"),
    (dict(class_id=ObjectClass.BALL, x=1.0, confidence=float("nan")), 0.0, "confidence must be in"),
    (dict(class_id=ObjectClass.BALL, x=float("nan"), confidence=0.5), 0.0, "position must be finite"),
    (dict(class_id=ObjectClass.BALL, x=1.0, confidence=0.5), float("inf"), "head_yaw must be finite"),
    (dict(class_id=ObjectClass.ROBOT, x=1.0, confidence=0.5, team=3), 0.0, "team must be 1, -1 or 0"),
])
def test_bad_rows_are_refused(row, head_yaw, message):
    with pytest.raises(ValueError, match=message):
        sv.soccer_vision_3d(rows(row), head_yaw=head_yaw)
