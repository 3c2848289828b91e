"""vision_msgs ⇄ DetectionArray: a simulator frame survives the round trip with everything the policy reads, the
covariance is the error model's, and foreign labels are dropped and named (docs/ros_graph.md, "Standard vision
messages")."""
import math

import numpy as np
import pytest

from dynenv_ros.envs.soccer_session import SoccerSession
from dynenv_ros.perception.covariance import position_covariance
from dynenv_ros.perception.params import load_preset
from dynenv_ros.ros.cdr import detection_array_cdr
from dynenv_ros.ros.vision_msgs_conversion import from_vision_msgs, to_vision_msgs
from dynenv_ros.soccer.config import SoccerConfig
from dynenv_msgs.msg import DetectionArray
from rclpy.serialization import deserialize_message
from vision_msgs.msg import Detection3DArray

F32 = 1e-5


def _frames(preset: str, periods: int = 6):
    config = SoccerConfig.from_mapping({"players_per_team": 2})
    session = SoccerSession(config, load_preset(preset), seed=5)
    session.reset(seed=5, kickoff_team=1)
    outputs = [session.initial()] + [session.step() for _ in range(periods)]
    for output in outputs:
        for k, frame in enumerate(output.frames):
            for i, robot in enumerate(frame.robots):
                data = detection_array_cdr(robot.detections, stamp_sec=1, stamp_nanosec=2, frame_id=f"r{i}/camera",
                                           robot_id=i, episode_id=output.episode_id,
                                           motion_period=output.motion_period, frame_index=k,
                                           frames_per_period=len(output.frames), head_yaw=0.0, fallen=False,
                                           penalized=False, kicking=False, ball_owner=0, ball_owner_seconds=0.0,
                                           game_seconds_remaining=0.0)
                yield deserialize_message(bytes(data), DetectionArray)


def _same(a: float, b: float) -> bool:
    return (math.isnan(a) and math.isnan(b)) or abs(a - b) <= F32 * max(1.0, abs(a))


@pytest.mark.parametrize("preset", ["realistic", "none"])
def test_round_trip_keeps_what_the_policy_reads(preset):
    params = load_preset(preset)
    compared = lines = robots = 0
    for msg in _frames(preset):
        vision = to_vision_msgs(msg, params)
        assert isinstance(vision, Detection3DArray) and len(vision.detections) == len(msg.detections)
        back, dropped = from_vision_msgs(vision, params, robot_id=msg.robot_id, episode_id=msg.episode_id,
                                         motion_period=msg.motion_period, frame_index=msg.frame_index,
                                         frames_per_period=msg.frames_per_period)
        assert dropped == []
        assert back.header.frame_id == msg.header.frame_id
        for a, b in zip(msg.detections, back.detections):
            assert (a.class_id, a.team, a.subtype, a.fallen, a.penalized) == (b.class_id, b.team, b.subtype,
                                                                              b.fallen, b.penalized)
            for field in ("confidence", "yaw", "size_x", "size_y"):
                assert _same(getattr(a, field), getattr(b, field)), (field, a, b)
            for point in ("position", "line_start", "line_end"):
                pa, pb = getattr(a, point), getattr(b, point)
                assert abs(pa.x - pb.x) < 1e-4 and abs(pa.y - pb.y) < 1e-4, (point, a, b)
            if preset == "none":      # exact geometry: DISTANT and PARTIAL are the simulator's own
                assert (a.sighting & 3) == (b.sighting & 3), (a, b)
            compared += 1
            lines += a.class_id == 6
            robots += a.class_id == 2
    assert compared > 200 and lines > 20 and robots > 10


def test_covariance_is_the_error_models_in_the_camera_frame():
    params = load_preset("realistic", noise_magnitude=2.0)
    msg = next(m for m in _frames("realistic") if any(d.class_id == 1 for d in m.detections))
    vision = to_vision_msgs(load_msg := msg, params)
    k = next(i for i, d in enumerate(load_msg.detections) if d.class_id == 1)
    d = load_msg.detections[k]
    cov = np.array(vision.detections[k].results[0].pose.covariance).reshape(6, 6)
    expected = position_covariance(params, np.array(d.position.x), np.array(d.position.y),
                                   np.array(params.classes[1].near_range), np.array(d.sighting))
    assert cov[:2, :2] == pytest.approx(expected)
    distance = math.hypot(d.position.x, d.position.y)       # docs: radial σ = m·(0.01 + 0.0175·d²)
    assert np.trace(cov[:2, :2]) == pytest.approx((2 * (0.01 + 0.0175 * distance ** 2)) ** 2
                                                  + (2 * 0.0175 * distance) ** 2)
    assert cov[2, 2] == cov[3, 3] == cov[4, 4] == 0.0 and cov[5, 5] > 0


def test_foreign_and_non_finite_detections_are_dropped_by_name():
    params = load_preset("realistic")
    msg = next(m for m in _frames("realistic") if len(m.detections) >= 2)
    vision = to_vision_msgs(msg, params)
    vision.detections[0].results[0].hypothesis.class_id = "sports ball"
    vision.detections[1].results[0].pose.pose.position.x = float("nan")
    back, dropped = from_vision_msgs(vision, params, robot_id=0, episode_id=1, motion_period=0, frame_index=0,
                                     frames_per_period=5)
    assert len(back.detections) == len(msg.detections) - 2
    assert dropped[0] == "sports ball" and dropped[1].endswith("(not finite)")
