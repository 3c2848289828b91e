"""TF: composing the published transforms places every detection where the ground truth has the object.

With the noise-free perception preset a detection's position in ``<robot>/camera`` is exact, so
map → base_link → camera applied to it must give the object's map position (docs/ros_graph.md, "TF").
"""
import math

import pytest

from builtin_interfaces.msg import Time
from dynenv_ros.envs.soccer_session import SoccerSession
from dynenv_ros.perception.params import load_preset
from dynenv_ros.ros.tf import robot_transforms, static_transforms
from dynenv_ros.soccer.config import SoccerConfig, robot_names


def _yaw(q) -> float:
    return 2.0 * math.atan2(q.z, q.w)


def _apply(transform, x: float, y: float) -> tuple[float, float]:
    """Child-frame point → parent frame, for a planar transform."""
    t, yaw = transform.transform.translation, _yaw(transform.transform.rotation)
    return t.x + math.cos(yaw) * x - math.sin(yaw) * y, t.y + math.sin(yaw) * x + math.cos(yaw) * y


def test_tf_chain_puts_exact_detections_on_their_objects():
    config = SoccerConfig.from_mapping({"players_per_team": 2, "falls": {"enabled": False}})
    session = SoccerSession(config, load_preset("none"), seed=3)
    session.reset(seed=3, kickoff_team=1)
    names = robot_names(2)
    checked = 0
    outputs = [session.initial()]
    for period in range(1, 11):       # turn the heads both ways and walk, so neither transform is the identity
        for robot in range(len(names)):
            session.submit(robot, session.episode_id, period, walk=1, turn=robot % 3, kick=0,
                           head_yaw_delta=0.4 if robot % 2 else -0.4)
        outputs.append(session.step())
    assert any(abs(o.head_yaw) > 0.3 for o in outputs[-1].frames[-1].snapshot.objects[:len(names)])
    for output in outputs:
        frame = output.frames[-1]
        by_id = {o.id: o for o in frame.snapshot.objects}
        poses = [(o.x, o.y, o.yaw, o.head_yaw) for o in frame.snapshot.objects[:len(names)]]
        tf = robot_transforms(names, poses, Time(sec=1))
        frames = {(t.header.frame_id, t.child_frame_id): t for t in tf.transforms}
        for i, robot in enumerate(frame.robots):
            base = frames[("map", f"{names[i]}/base_link")]
            camera = frames[(f"{names[i]}/base_link", f"{names[i]}/camera")]
            for row in robot.detections:
                if row["true_id"] < 0 or row["true_id"] not in by_id:
                    continue
                truth = by_id[row["true_id"]]
                x, y = _apply(base, *_apply(camera, float(row["x"]), float(row["y"])))
                assert (x, y) == pytest.approx((truth.x, truth.y), abs=1e-3), (names[i], row)
                checked += 1
    assert checked >= 20      # the ball, robots and posts were seen often enough to mean something


def test_quaternions_are_unit_and_yaw_only():
    tf = robot_transforms(["r"], [(1.0, -2.0, 2.5, -1.0)], Time())
    for t in tf.transforms:
        q = t.transform.rotation
        assert (q.x, q.y) == (0.0, 0.0)
        assert q.x ** 2 + q.y ** 2 + q.z ** 2 + q.w ** 2 == pytest.approx(1.0)
    assert _yaw(tf.transforms[0].transform.rotation) == pytest.approx(2.5)
    assert _yaw(tf.transforms[1].transform.rotation) == pytest.approx(-1.0)


def test_static_team_frames_turn_team_b_by_pi():
    """The team frame of the learning targets: team B's field frame is map turned by π (x toward team A's goal)."""
    frames = {t.child_frame_id: t for t in static_transforms(Time()).transforms}
    assert set(frames) == {"team_a/field", "team_b/field"}
    assert _apply(frames["team_a/field"], 1.0, 2.0) == pytest.approx((1.0, 2.0))
    assert _apply(frames["team_b/field"], 1.0, 2.0) == pytest.approx((-1.0, -2.0))


def test_mismatched_names_and_poses_are_refused():
    with pytest.raises(ValueError, match="2 robot names but 1 poses"):
        robot_transforms(["a", "b"], [(0.0, 0.0, 0.0, 0.0)], Time())


def test_the_simulator_publishes_the_tree_and_latches_the_team_frames(make_node, executor):
    """Every robot's odom, base_link, camera and ground-truth frame on /tf with each frame's stamp; a late
    subscriber still gets /tf_static."""
    from rclpy.parameter import Parameter
    from tf2_msgs.msg import TFMessage

    from dynenv_ros.nodes.sim_node import SimNode
    from dynenv_ros.ros.tf import tf_static_qos
    from ros_harness import spin_until

    sim = make_node(SimNode, parameter_overrides=[Parameter(k, value=v) for k, v in dict(
        players_per_team=1, seed=2, mode="realtime", real_time_factor=10.0, publish_markers=False).items()])
    listener = make_node("tf_listener")
    dynamic: list[TFMessage] = []
    listener.create_subscription(TFMessage, "/tf", dynamic.append, 100)
    for node in (sim, listener):
        executor.add_node(node)
    assert spin_until(executor, lambda: len(dynamic) >= 3, 20.0)
    static: list[TFMessage] = []
    listener.create_subscription(TFMessage, "/tf_static", static.append, tf_static_qos())
    assert spin_until(executor, lambda: static, 10.0)
    children = {t.child_frame_id: t.header.frame_id for t in dynamic[-1].transforms}
    tree = {}
    for robot in ("team_a_0", "team_b_0"):       # self-localization is on by default: REP 105's chain
        tree.update({f"{robot}/odom": "map", f"{robot}/base_link": f"{robot}/odom",
                     f"{robot}/camera": f"{robot}/base_link", f"{robot}/ground_truth/base_link": "map"})
    assert children == tree
    stamps = [(m.transforms[0].header.stamp.sec, m.transforms[0].header.stamp.nanosec) for m in dynamic]
    assert stamps == sorted(stamps) and len(set(stamps)) == len(stamps)      # one tree per frame, in sim time
    assert {t.child_frame_id for t in static[0].transforms} == {"team_a/field", "team_b/field"}
