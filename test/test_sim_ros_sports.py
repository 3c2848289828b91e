"""The simulator's ros-sports option (``ros_sports``, default off): beside each robot's DetectionArray, the same frame
as soccer_vision_3d_msgs in the robot's base_link, and the game as RCGCD15 on <robot>/gc/data once per period."""
from __future__ import annotations

import math

import pytest
from dynenv_msgs.msg import Action, DetectionArray
from game_controller_spl_interfaces.msg import RCGCD15
from rclpy.exceptions import ParameterException
from rclpy.parameter import Parameter
from soccer_vision_3d_msgs.msg import BallArray, GoalpostArray, MarkingArray, RobotArray

from dynenv_ros.nodes.sim_node import SimNode
from dynenv_ros.ros import topics
from dynenv_ros.ros.qos import sim_stream
from ros_harness import spin_until

ROBOTS = ["team_a_0", "team_b_0"]


def _sim(make_node, **params):
    defaults = {"players_per_team": 1, "seed": 7, "falls_enabled": False, "publish_markers": False}
    defaults.update(params)
    return make_node(SimNode, parameter_overrides=[Parameter(k, value=v) for k, v in defaults.items()])


def test_ros_sports_messages_mirror_each_frame_and_the_game(make_node, executor):
    sim = _sim(make_node, ros_sports=True, gc_team_number_a=21, gc_team_number_b=22)
    executor.add_node(sim)
    probe = make_node("probe")
    qos = sim_stream()
    got: dict[str, list] = {k: [] for k in ("detections", "balls", "robots", "goalposts", "markings", "gc")}
    probe.create_subscription(DetectionArray, topics.detections("team_a_0"), got["detections"].append, qos)
    probe.create_subscription(DetectionArray, topics.detections("team_b_0"), lambda m: None, qos)
    for robot in ROBOTS:        # the first observation waits for someone to act for every robot
        probe.create_publisher(Action, topics.action(robot), qos)
    for kind, cls in (("balls", BallArray), ("robots", RobotArray), ("goalposts", GoalpostArray),
                      ("markings", MarkingArray)):
        probe.create_subscription(cls, topics.soccer_vision_3d("team_a_0", kind), got[kind].append, qos)
    probe.create_subscription(RCGCD15, topics.gc_data("team_a_0"), got["gc"].append, qos)
    executor.add_node(probe)
    assert spin_until(executor, lambda: all(len(got[k]) >= 5 for k in ("detections", "balls", "robots",
                                                                           "goalposts", "markings"))
                      and got["gc"], 20.0)
    for k in range(5):
        det = got["detections"][k]
        for kind in ("balls", "robots", "goalposts", "markings"):
            msg = got[kind][k]
            assert msg.header.frame_id == "team_a_0/base_link"
            assert (msg.header.stamp.sec, msg.header.stamp.nanosec) == (det.header.stamp.sec, det.header.stamp.nanosec)
        c, s = math.cos(det.head_yaw), math.sin(det.head_yaw)
        balls = [d for d in det.detections if d.class_id == d.CLASS_BALL]
        assert len(got["balls"][k].balls) == len(balls)
        for ball, d in zip(got["balls"][k].balls, balls):
            assert math.isclose(ball.center.x, c * d.position.x - s * d.position.y, abs_tol=1e-5)
            assert math.isclose(ball.center.y, s * d.position.x + c * d.position.y, abs_tol=1e-5)
            assert math.isclose(ball.confidence.confidence, d.confidence, abs_tol=1e-6)
        robots = [d for d in det.detections if d.class_id == d.CLASS_ROBOT]
        assert len(got["robots"][k].robots) == len(robots)
        lines = [d for d in det.detections if d.class_id == d.CLASS_FIELD_LINE]
        assert len(got["markings"][k].segments) == len(lines)
    assert any(got["balls"][k].balls for k in range(5))        # the ball lies ahead at kickoff
    gc = got["gc"][0]
    assert (gc.packet_number, gc.players_per_team, gc.state, gc.set_play, gc.first_half) == (0, 1, 3, 0, 1)
    assert (gc.teams[0].team_number, gc.teams[1].team_number) == (21, 22)
    assert gc.kicking_team == 21 and gc.secondary_time == 10       # team A's kick-off, 10 s until the ball is free
    assert gc.secs_remaining == 120
    assert [p.penalty for p in gc.teams[0].players] == [0] + [14] * 19


def test_ros_sports_is_off_by_default(make_node):
    sim = _sim(make_node)
    assert not sim.settings.ros_sports
    names = {name for name, _ in sim.get_publisher_names_and_types_by_node("sim_node", sim.get_namespace())}
    assert not any("soccer_vision_3d" in n or n.endswith("/gc/data") for n in names)


@pytest.mark.parametrize("params, message", [
    ({"ros_sports": True, "gc_team_number_a": 5, "gc_team_number_b": 5}, "distinct numbers"),
    ({"ros_sports": True, "gc_team_number_a": 0}, "gc_team_number_a"),
])
def test_bad_ros_sports_parameters_are_refused(make_node, params, message):
    with pytest.raises(ParameterException, match=message):
        _sim(make_node, **params)
