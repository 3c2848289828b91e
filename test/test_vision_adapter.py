"""The vision adapter node: the simulator's detections come out as vision_msgs, and a robot's own vision_msgs
detections come back as the DetectionArray the policy node reads, frames numbered from their stamps."""
from __future__ import annotations

from diagnostic_msgs.msg import DiagnosticArray
from dynenv_msgs.msg import Detection, DetectionArray
from geometry_msgs.msg import Point
from rclpy.parameter import Parameter
from sensor_msgs.msg import JointState
from std_msgs.msg import Bool, Float32MultiArray
from vision_msgs.msg import Detection3DArray

from dynenv_ros.nodes.sim_node import SimNode
from dynenv_ros.nodes.vision_adapter import VisionAdapter
from dynenv_ros.ros.vision_msgs_conversion import to_vision_msgs
from dynenv_ros.perception.params import load_preset
from ros_harness import spin_until


def _params(**values):
    return [Parameter(k, value=v) for k, v in values.items()]


def test_forward_republishes_the_simulators_detections_with_covariances(make_node, executor):
    sim = make_node(SimNode, parameter_overrides=_params(players_per_team=1, seed=2, mode="realtime",
                                                        real_time_factor=10.0, publish_markers=False))
    adapter = make_node(VisionAdapter, parameter_overrides=_params(players_per_team=1))
    listener = make_node("listener")
    got: list[Detection3DArray] = []
    listener.create_subscription(Detection3DArray, "/team_a_0/detections_3d", got.append, 10)
    for node in (sim, adapter, listener):
        executor.add_node(node)
    assert spin_until(executor, lambda: sum(len(m.detections) for m in got) >= 10, 20.0)
    assert all(m.header.frame_id == "team_a_0/camera" for m in got)
    det = next(d for m in got for d in m.detections)
    assert det.results[0].hypothesis.class_id.split("/")[0] in {
        "ball", "robot", "goalpost", "penalty_cross", "line_crossing", "field_line", "center_circle", "unknown"}
    assert 0.0 <= det.results[0].hypothesis.score <= 1.0
    assert any(m.detections and m.detections[0].results[0].pose.covariance[0] > 0 for m in got)


def test_reverse_numbers_frames_from_stamps_and_drops_foreign_labels(make_node, executor):
    adapter = make_node(VisionAdapter, parameter_overrides=_params(players_per_team=1, reverse=True,
                                                                    vision_hz=10.0, frames_per_period=5))
    talker = make_node("talker")
    publisher = talker.create_publisher(Detection3DArray, "/team_b_0/detections_3d", 10)
    got: list[DetectionArray] = []
    talker.create_subscription(DetectionArray, "/team_b_0/detections", got.append, 10)
    for node in (adapter, talker):
        executor.add_node(node)
    assert spin_until(executor, lambda: publisher.get_subscription_count() > 0, 10.0)
    source = DetectionArray(detections=[Detection(class_id=1, position=Point(x=1.0, y=0.2), confidence=0.9,
                                                  size_x=0.1, size_y=0.1, yaw=float("nan"))])
    message = to_vision_msgs(source, load_preset("realistic"))
    message.header.stamp.sec, message.header.stamp.nanosec = 12, 300_000_000      # frame 123: period 24, index 3
    message.header.frame_id = "team_b_0/camera"
    foreign = to_vision_msgs(source, load_preset("realistic")).detections[0]
    foreign.results[0].hypothesis.class_id = "person"
    message.detections.append(foreign)
    publisher.publish(message)
    assert spin_until(executor, lambda: got, 10.0)
    out = got[0]
    assert (out.robot_id, out.motion_period, out.frame_index, out.frames_per_period) == (1, 24, 3, 5)
    assert len(out.detections) == 1 and out.detections[0].class_id == 1
    assert abs(out.detections[0].position.x - 1.0) < 1e-6
    assert adapter.dropped == {"person": 1}


def test_a_vision_stack_publishing_vision_msgs_drives_the_policy_node_through_the_reverse_adapter(make_node,
                                                                                                  executor):
    """docs/deploy.md's route for a robot whose own vision publishes Detection3DArray: reverse adapter, then the
    policy node, which answers the period with an action stamped like its last frame."""
    from dynenv_msgs.msg import Action

    from policy_node.policy_node import PolicyNode
    adapter = make_node(VisionAdapter, parameter_overrides=_params(players_per_team=1, robots=["team_a_0"],
                                                                    reverse=True, vision_hz=10.0,
                                                                    frames_per_period=5))
    policy = make_node(PolicyNode, parameter_overrides=_params(players_per_team=1, team="a", seed=3))
    robot_vision = make_node("robot_vision")
    publisher = robot_vision.create_publisher(Detection3DArray, "/team_a_0/detections_3d", 10)
    actions: list[Action] = []
    robot_vision.create_subscription(Action, "/team_a_0/action", actions.append, 10)
    for node in (adapter, policy, robot_vision):
        executor.add_node(node)
    assert spin_until(executor, lambda: publisher.get_subscription_count() > 0
                      and robot_vision.count_publishers("/team_a_0/action") > 0, 10.0)
    params = load_preset("realistic")
    for frame in range(5, 10):                                   # frames 5..9 at 10 Hz: motion period 1, complete
        ball = DetectionArray(detections=[Detection(class_id=1, position=Point(x=1.0 + 0.1 * frame, y=0.2),
                                                    confidence=0.9, size_x=0.1, size_y=0.1, yaw=float("nan"))])
        message = to_vision_msgs(ball, params)
        message.header.stamp.sec, message.header.stamp.nanosec = 0, frame * 100_000_000
        message.header.frame_id = "team_a_0/camera"
        publisher.publish(message)
    assert spin_until(executor, lambda: actions, 20.0)
    action = actions[0]
    assert action.robot_id == 0 and action.motion_period == 2
    assert (action.header.stamp.sec, action.header.stamp.nanosec) == (0, 900_000_000)
    assert action.header.frame_id == "team_a_0/base_link"


def _ball_message(stamp_ns: int) -> Detection3DArray:
    source = DetectionArray(detections=[Detection(class_id=1, position=Point(x=1.0, y=0.2), confidence=0.9,
                                                  size_x=0.1, size_y=0.1, yaw=float("nan"))])
    message = to_vision_msgs(source, load_preset("realistic"))
    message.header.stamp.sec, message.header.stamp.nanosec = divmod(stamp_ns, 1_000_000_000)
    message.header.frame_id = "team_a_0/camera"
    return message


def test_reverse_refuses_duplicate_and_off_grid_frames_and_counts_them(make_node, executor):
    """docs/deploy.md, "A real camera's timing": the grid is centred on the first stamp; a second frame for a filled
    slot and one half-way between two slots are refused, counted, and never reach the policy node."""
    adapter = make_node(VisionAdapter, parameter_overrides=_params(players_per_team=1, robots=["team_a_0"],
                                                                    reverse=True, vision_hz=10.0))
    talker = make_node("talker")
    publisher = talker.create_publisher(Detection3DArray, "/team_a_0/detections_3d", 10)
    got: list[DetectionArray] = []
    talker.create_subscription(DetectionArray, "/team_a_0/detections", got.append, 10)
    for node in (adapter, talker):
        executor.add_node(node)
    assert spin_until(executor, lambda: publisher.get_subscription_count() > 0, 10.0)
    base = 1_700_000_000_049_000_000                  # half an interval (minus 1 ms) past the 100 ms grid
    for offset_ms in (0, 4, 50, 103):                 # slot s; s again; half-way; s + 1 (3 ms late)
        publisher.publish(_ball_message(base + offset_ms * 1_000_000))
    assert spin_until(executor, lambda: adapter.received == 4 and len(got) == 2, 10.0)
    assert [(m.motion_period * 5 + m.frame_index) - (got[0].motion_period * 5 + got[0].frame_index)
            for m in got] == [0, 1]
    assert adapter.counts["frames_duplicate"] == 1 and adapter.counts["frames_out_of_tolerance"] == 1
    assert adapter.diagnostics()["frames_converted"] == "2"


def test_the_robots_own_state_fills_the_adapters_frames(make_node, executor):
    """Head yaw from JointState (HeadYaw), fallen and penalized from Bool topics, the GameController's values from a
    Float32MultiArray; counted in the adapter's diagnostics, and defaults where a value is missing."""
    adapter = make_node(VisionAdapter, parameter_overrides=_params(players_per_team=1, robots=["team_a_0"],
                                                                    reverse=True, diagnostics_period=0.1))
    robot = make_node("robot")
    camera = robot.create_publisher(Detection3DArray, "/team_a_0/detections_3d", 10)
    joints = robot.create_publisher(JointState, "/team_a_0/joint_states", 10)
    fallen = robot.create_publisher(Bool, "/team_a_0/fallen", 10)
    game = robot.create_publisher(Float32MultiArray, "/team_a_0/game_state", 10)
    frames: list[DetectionArray] = []
    diagnostics: list[DiagnosticArray] = []
    robot.create_subscription(DetectionArray, "/team_a_0/detections", frames.append, 10)
    robot.create_subscription(DiagnosticArray, "/vision_adapter/diagnostics", diagnostics.append, 10)
    for node in (adapter, robot):
        executor.add_node(node)
    assert spin_until(executor, lambda: all(p.get_subscription_count() > 0 for p in (camera, joints, fallen, game)),
                      10.0)
    now = adapter.get_clock().now().nanoseconds
    joint = JointState(name=["HeadPitch", "HeadYaw"], position=[0.1, 0.35])
    joint.header.stamp.sec, joint.header.stamp.nanosec = divmod(now, 1_000_000_000)
    joints.publish(joint)
    fallen.publish(Bool(data=True))
    game.publish(Float32MultiArray(data=[-1.0, 7.5, 300.0]))
    game.publish(Float32MultiArray(data=[3.0, 7.5, 300.0]))                     # refused: no such ball owner
    assert spin_until(executor, lambda: adapter.counts["state_malformed"] == 1
                      and adapter.states["team_a_0"].latest.keys() >= {"fallen", "game_state"}
                      and adapter.states["team_a_0"].head_stamps, 10.0)
    camera.publish(_ball_message(now + 20_000_000))
    assert spin_until(executor, lambda: frames, 10.0)
    out = frames[0]
    assert abs(out.head_yaw - 0.35) < 1e-6 and out.self_fallen and not out.self_penalized
    assert (out.ball_owner, out.ball_owner_seconds, out.game_seconds_remaining) == (-1, 7.5, 300.0)
    assert adapter.counts["head_yaw_used"] == 1 and adapter.counts["penalized_missing"] == 1
    assert spin_until(executor, lambda: any(s.values and any(v.key == "state_malformed" and v.value == "1"
                                                             for v in s.values) for d in diagnostics
                                            for s in d.status), 10.0)
