"""The ros-sports interfaces rebuilt from msg_defs/upstream (issue 41): upstream's files byte for byte, rosidl's type
hashes equal to rosbags' independent computation, the ROS-free constants equal to the messages', and the records of
perception/soccer_vision_3d.py and gamecontroller/ copied into the messages field for field."""
from __future__ import annotations

import hashlib
import json
import math
import sys
from pathlib import Path

import pytest

from dynenv_ros.gamecontroller import packet as gc
from dynenv_ros.perception import soccer_vision_3d as sv

REPO = Path(__file__).resolve().parent.parent
UPSTREAM = REPO / "msg_defs" / "upstream"
# Git blob hashes of upstream's files: ros-sports/soccer_interfaces 8c1ee2888e004fe095436b96b448142c2b4db837 and
# ros-sports/game_controller_spl b058218ae267dce8ecabf5574f1b01671f68f977 (`git ls-tree -r COMMIT`).
UPSTREAM_BLOBS = {
    "soccer_vision_attribute_msgs/msg/Confidence.msg": "e1567db53308eb3e64e01941a4491460083d9174",
    "soccer_vision_attribute_msgs/msg/Goalpost.msg": "fe290f8a9d95a5e54629e286463a40f616a3ca10",
    "soccer_vision_attribute_msgs/msg/Robot.msg": "91c4a85300d57e6964dafe65ea62309b7aaa1a6b",
    "soccer_vision_3d_msgs/msg/Ball.msg": "1cba9ba91217e34d91234d9be96bb62aad637226",
    "soccer_vision_3d_msgs/msg/BallArray.msg": "8b0db4841f4ea0f1a468ed633aea5f64677a79f0",
    "soccer_vision_3d_msgs/msg/FieldBoundary.msg": "70cde13bcd3373d791e6e09843e2b8f6814ec016",
    "soccer_vision_3d_msgs/msg/Goalpost.msg": "26c18c5288516a001b7d11a1c9d0f7f6575c1330",
    "soccer_vision_3d_msgs/msg/GoalpostArray.msg": "6d3ce0c23f7821e36f9f3191c32e2d5f340d6ebb",
    "soccer_vision_3d_msgs/msg/MarkingArray.msg": "d281f71cffd696c6024893f74fa56e9ddd2b0c29",
    "soccer_vision_3d_msgs/msg/MarkingEllipse.msg": "60e35649dfd1b3cd5ccbfb447b21b65fabbcc9f9",
    "soccer_vision_3d_msgs/msg/MarkingIntersection.msg": "b4f852ab15cb017b3b16ee6d8c2ad059a6577703",
    "soccer_vision_3d_msgs/msg/MarkingSegment.msg": "fe7f8b535fa601ae44f4be69cd01eb147aced44a",
    "soccer_vision_3d_msgs/msg/Obstacle.msg": "4f665d9c9c469f9bfc48586f4594fa213d36224a",
    "soccer_vision_3d_msgs/msg/ObstacleArray.msg": "a7ccac9b8186b9348ddec1be2868c7384c9f7538",
    "soccer_vision_3d_msgs/msg/Robot.msg": "4d052259f3ad14d2340c59ebf9f64fe8becc84c3",
    "soccer_vision_3d_msgs/msg/RobotArray.msg": "9579b58d9bafee9e973e94b5db0a115882c31984",
    "game_controller_spl_interfaces/msg/RCGCD15.msg": "5a16e5f4713925e149ca15983ec49c92c2fc2265",
    "game_controller_spl_interfaces/msg/TeamInfo15.msg": "5f3a123e09182ad58bb0b6e2e5b3a69e6a0b39fe",
    "game_controller_spl_interfaces/msg/RobotInfo15.msg": "2c5baaf4772de2ca941da5fbc7bf95c022195dff",
    "game_controller_spl_interfaces/msg/RCGCRD4.msg": "f0845df467d9c3fe2b057f94e4f492c570f3f305",
}
TYPES = [f"{path.split('/')[0]}/msg/{Path(path).stem}" for path in UPSTREAM_BLOBS]


def git_blob_hash(path: Path) -> str:
    data = path.read_bytes()
    return hashlib.sha1(b"blob %d\0" % len(data) + data).hexdigest()


def generated_hash(name: str) -> str:
    package, kind, type_name = name.split("/")
    description = json.loads((Path(sys.prefix) / "share" / package / kind / f"{type_name}.json").read_text())
    return next(e["hash_string"] for e in description["type_hashes"] if e["type_name"] == name)


def test_the_msg_files_are_upstreams_byte_for_byte():
    found = {str(p.relative_to(UPSTREAM)) for package in ("soccer_vision_attribute_msgs", "soccer_vision_3d_msgs",
                                                           "game_controller_spl_interfaces")
             for p in (UPSTREAM / package / "msg").glob("*.msg")}
    assert found == set(UPSTREAM_BLOBS)
    assert {path: git_blob_hash(UPSTREAM / path) for path in UPSTREAM_BLOBS} == UPSTREAM_BLOBS


def test_the_packages_generate_every_msg_and_the_bootstrap_builds_them_in_order():
    for package in ("soccer_vision_attribute_msgs", "soccer_vision_3d_msgs", "game_controller_spl_interfaces"):
        cmake = (UPSTREAM / package / "CMakeLists.txt").read_text()
        for path in (UPSTREAM / package / "msg").glob("*.msg"):
            assert f'"msg/{path.name}"' in cmake, path
    bootstrap = (REPO / "tools" / "bootstrap.py").read_text()
    order = [bootstrap.index(f'"{name}"') for name in ("vision_msgs", "soccer_vision_attribute_msgs",
                                                        "soccer_vision_3d_msgs", "game_controller_spl_interfaces")]
    assert order == sorted(order)      # dependencies first


@pytest.mark.parametrize("name", TYPES)
def test_rosidl_hash_equals_rosbags_independent_hash(name):
    """Two implementations of RIHS01 over the same definitions (and, with the blob check, upstream's)."""
    from dynenv_ros.bags.typestore import dynenv_typestore
    assert generated_hash(name) == dynenv_typestore().hash_rihs01(name)


def test_the_ros_free_constants_are_the_messages():
    from game_controller_spl_interfaces.msg import RCGCD15, RobotInfo15, TeamInfo15
    from soccer_vision_3d_msgs.msg import Ball as BallMsg, Goalpost as GoalpostMsg, Robot as RobotMsg
    # soccer_vision_attribute_msgs' types, reached through the 3D messages (the package is not imported by name)
    Confidence, Goalpost, Robot = (type(BallMsg().confidence), type(GoalpostMsg().attributes),
                                   type(RobotMsg().attributes))
    assert (sv.TEAM_UNKNOWN, sv.TEAM_OWN, sv.TEAM_OPPONENT) == (Robot.TEAM_UNKNOWN, Robot.TEAM_OWN,
                                                                Robot.TEAM_OPPONENT)
    assert (sv.TEAM_UNKNOWN, sv.TEAM_OWN, sv.TEAM_OPPONENT, sv.SIDE_UNKNOWN) == (
        Goalpost.TEAM_UNKNOWN, Goalpost.TEAM_OWN, Goalpost.TEAM_OPPONENT, Goalpost.SIDE_UNKNOWN)
    assert [getattr(sv, f"STATE_{s}") for s in ("UNKNOWN", "STANDING", "FALLEN", "KICKING", "INACTIVE")] == [
        getattr(Robot, f"STATE_{s}") for s in ("UNKNOWN", "STANDING", "FALLEN", "KICKING", "INACTIVE")]
    assert [getattr(sv, f"FACING_{s}") for s in ("UNKNOWN", "THIS_WAY", "AWAY", "LEFT", "RIGHT")] == [
        getattr(Robot, f"FACING_{s}") for s in ("UNKNOWN", "THIS_WAY", "AWAY", "LEFT", "RIGHT")]
    assert Confidence().confidence == Confidence.CONFIDENCE_UNKNOWN == -1.0
    for name in ("STATE_INITIAL", "STATE_READY", "STATE_SET", "STATE_PLAYING", "STATE_FINISHED", "SET_PLAY_NONE",
                 "SET_PLAY_GOAL_KICK", "SET_PLAY_PUSHING_FREE_KICK", "SET_PLAY_CORNER_KICK", "SET_PLAY_KICK_IN",
                 "SET_PLAY_PENALTY_KICK", "GAME_PHASE_NORMAL", "COMPETITION_TYPE_NORMAL"):
        assert getattr(gc, name) == getattr(RCGCD15, name), name
    for name in ("PENALTY_NONE", "PENALTY_SPL_PLAYER_PUSHING", "PENALTY_SPL_INACTIVE_PLAYER",
                 "PENALTY_SPL_ILLEGAL_POSITION", "PENALTY_SPL_LEAVING_THE_FIELD", "PENALTY_SUBSTITUTE",
                 "PENALTY_MANUAL"):
        assert getattr(gc, name) == getattr(RobotInfo15, name), name
    assert (gc.TEAM_BLUE, gc.TEAM_RED) == (TeamInfo15.TEAM_BLUE, TeamInfo15.TEAM_RED)
    assert len(RCGCD15().teams) == 2 and len(TeamInfo15().players) == gc.MAX_NUM_PLAYERS


def test_detection_records_become_the_four_arrays():
    from std_msgs.msg import Header

    from dynenv_ros.ros.ros_sports_conversion import soccer_vision_messages
    frame = sv.SoccerVision3D(
        balls=[sv.Ball(1.0, 2.0, 0.05, 0.75)],
        robots=[sv.Robot(sv.Box(2.0, -1.0, 0.287, math.pi / 2, 0.3, 0.2, 0.574), sv.TEAM_OPPONENT, sv.STATE_FALLEN,
                         sv.FACING_LEFT, 0.5)],
        goalposts=[sv.Goalpost(sv.Box(4.0, 0.8, 0.4, 0.0, 0.1, 0.1, 0.8), 0.25)],
        segments=[sv.Segment((1.0, -1.0), (1.0, 2.0), 0.5)],
        intersections=[sv.Intersection(3.0, 1.0, 3, 0.625)],
        ellipses=[sv.Ellipse(2.0, 0.5, 1.5, 0.875)])
    header = Header(frame_id="team_a_0/base_link")
    header.stamp.sec, header.stamp.nanosec = 12, 500_000_000
    balls, robots, posts, markings = soccer_vision_messages(frame, header)
    for msg in (balls, robots, posts, markings):
        assert (msg.header.frame_id, msg.header.stamp.sec, msg.header.stamp.nanosec) == ("team_a_0/base_link", 12,
                                                                                         500_000_000)
    (ball,) = balls.balls
    assert (ball.center.x, ball.center.y, ball.center.z, ball.confidence.confidence) == (1.0, 2.0, 0.05, 0.75)
    (robot,) = robots.robots
    c = robot.bb.center
    assert (c.position.x, c.position.y, c.position.z) == (2.0, -1.0, 0.287)
    assert math.isclose(c.orientation.z, math.sqrt(0.5)) and math.isclose(c.orientation.w, math.sqrt(0.5))
    assert (robot.bb.size.x, robot.bb.size.y, robot.bb.size.z) == (0.3, 0.2, 0.574)
    a = robot.attributes
    assert (a.player_number, a.team, a.state, a.facing, robot.confidence.confidence) == (0, 2, 2, 3, 0.5)
    (post,) = posts.posts
    assert (post.bb.center.position.x, post.bb.center.orientation.w, post.attributes.side, post.attributes.team,
            post.confidence.confidence) == (4.0, 1.0, 0, 0, 0.25)
    (segment,) = markings.segments
    assert (segment.start.x, segment.start.y, segment.end.x, segment.end.y) == (1.0, -1.0, 1.0, 2.0)
    (cross,) = markings.intersections
    assert (cross.center.x, cross.center.y, cross.num_rays, list(cross.rays), cross.confidence.confidence) == (
        3.0, 1.0, 3, [], 0.625)
    (circle,) = markings.ellipses
    assert (circle.diameter, circle.center.position.x, circle.center.position.y, circle.center.orientation.w,
            circle.confidence.confidence) == (1.5, 2.0, 0.5, 1.0, 0.875)


def test_game_state_becomes_rcgcd15_and_return_data_rcgcrd4():
    from dynenv_ros.ros.ros_sports_conversion import rcgcd15, rcgcrd4, return_data
    players = (gc.RobotInfo(), gc.RobotInfo(gc.PENALTY_SPL_PLAYER_PUSHING, 18)) + (gc.RobotInfo(14, 0),) * 18
    data = gc.GameControlData(teams=(gc.TeamInfo(team_number=12, score=2, players=players),
                                     gc.TeamInfo(team_number=34, field_player_colour=1, goalkeeper_colour=1, score=1)),
                              packet_number=44, players_per_team=2, state=3, set_play=4, kicking_team=34,
                              secs_remaining=84, secondary_time=13)
    msg = rcgcd15(data)
    assert (msg.packet_number, msg.players_per_team, msg.state, msg.set_play, msg.first_half, msg.kicking_team,
            msg.secs_remaining, msg.secondary_time) == (44, 2, 3, 4, 1, 34, 84, 13)
    a, b = msg.teams
    assert (a.team_number, a.score, a.message_budget, a.goalkeeper, a.team_colour) == (12, 2, 1200, 1, 0)
    assert (b.team_number, b.score, b.field_player_colour) == (34, 1, 1)
    assert [(p.penalty, p.secs_till_unpenalised) for p in a.players] == [(0, 0), (2, 18)] + [(14, 0)] * 18
    back = gc.ReturnData(player_num=2, team_num=12, fallen=True, pose=(1500.0, -250.0, 0.5), ball_age=1.5,
                         ball=(800.0, 100.0))
    out = rcgcrd4(back)
    assert (out.player_num, out.team_num, out.fallen, list(out.pose), out.ball_age, list(out.ball)) == (
        2, 12, 1, [1500.0, -250.0, 0.5], 1.5, [800.0, 100.0])
    assert return_data(out) == back
