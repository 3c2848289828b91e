"""The fast DetectionArray serialiser gives messages rclpy reads back field for field, for every head length."""
import numpy as np
import pytest
from rclpy.serialization import deserialize_message, serialize_message

from dynenv_msgs.msg import DetectionArray
from dynenv_ros.envs.soccer_session import SoccerSession
from dynenv_ros.perception.params import load_preset
from dynenv_ros.ros import conversions as cv
from dynenv_ros.ros.cdr import detection_array_cdr
from dynenv_ros.ros.interfaces import field_differences
from dynenv_ros.soccer.config import SoccerConfig


def _rows(count, seed=0):
    session = SoccerSession(SoccerConfig(players_per_team=5), load_preset("realistic", noise_magnitude=3.0),
                            seed=seed)
    rows = np.concatenate([r.detections for f in session.step().frames for r in f.robots])
    assert len(rows) >= count and set(np.unique(rows["class_id"])) >= {1, 2, 3, 6}
    return rows[:count]


@pytest.mark.parametrize("frame_id", ["", "a", "team_a_0/camera", "team_b_12/camera", "x" * 13])
@pytest.mark.parametrize("count", [0, 1, 2, 7, 40])
def test_fast_serialisation_reads_back_as_the_slow_one(frame_id, count):
    rows = _rows(count)
    fields = dict(robot_id=3, episode_id=9, motion_period=41, frame_index=4, frames_per_period=5, head_yaw=-0.75,
                  fallen=True, penalized=False, kicking=True, ball_owner=-1, ball_owner_seconds=7.25,
                  game_seconds_remaining=93.5)
    stamp = cv.Time(sec=12, nanosec=345_000_000)
    slow = cv.detection_array(rows, robot_name=frame_id.split("/")[0], stamp=stamp, **fields)
    slow.header.frame_id = frame_id
    fast = deserialize_message(detection_array_cdr(rows, stamp_sec=12, stamp_nanosec=345_000_000,
                                                   frame_id=frame_id, **fields), DetectionArray)
    assert field_differences(slow, fast) == []


@pytest.mark.parametrize("kicking, ball_owner, ball_owner_seconds, game_seconds_remaining",
                         [(False, 0, 0.0, 0.0), (True, 1, 9.9, 119.9), (False, -1, 24.6, 0.05), (True, -1, 0.1, 1e-3)])
@pytest.mark.parametrize("frame_id", ["", "team_a_0/camera", "team_b_12/ca"])
def test_fast_serialisation_carries_the_robots_own_kick_and_the_game_controller(
        kicking, ball_owner, ball_owner_seconds, game_seconds_remaining, frame_id):
    rows = _rows(3)
    fields = dict(robot_id=1, episode_id=2, motion_period=3, frame_index=0, frames_per_period=5, head_yaw=0.5,
                  fallen=False, penalized=True, kicking=kicking, ball_owner=ball_owner,
                  ball_owner_seconds=ball_owner_seconds, game_seconds_remaining=game_seconds_remaining)
    stamp = cv.Time(sec=1, nanosec=5)
    slow = cv.detection_array(rows, robot_name="x", stamp=stamp, **fields)
    slow.header.frame_id = frame_id
    wire = serialize_message(slow)
    fast_bytes = detection_array_cdr(rows, stamp_sec=1, stamp_nanosec=5, frame_id=frame_id, **fields)
    fast = deserialize_message(fast_bytes, DetectionArray)
    # equal to rclpy's serialisation of the same message (float32 fields rounded alike), and as long
    assert field_differences(deserialize_message(wire, DetectionArray), fast) == []
    assert len(fast_bytes) == len(wire)
    assert (fast.self_kicking, fast.ball_owner) == (kicking, ball_owner)
    assert fast.ball_owner_seconds == pytest.approx(ball_owner_seconds, rel=1e-6)
    assert fast.game_seconds_remaining == pytest.approx(game_seconds_remaining, rel=1e-6)


def test_a_sessions_frames_serialise_fast_as_rclpy_does():
    """The values the simulator node publishes (kick-off ownership for both teams, the game clock) survive the fast
    path exactly as rclpy's serialisation of the same message."""
    session = SoccerSession(SoccerConfig(players_per_team=2), load_preset("realistic"), seed=1)
    frames = session.initial().frames + session.step().frames
    owners = set()
    for frame in frames:
        for i, robot in enumerate(frame.robots):
            fields = dict(robot_id=i, episode_id=session.episode_id, motion_period=0, frame_index=frame.frame_index,
                          frames_per_period=5, head_yaw=robot.head_yaw, fallen=robot.fallen,
                          penalized=robot.penalized, kicking=robot.kicking, ball_owner=robot.ball_owner,
                          ball_owner_seconds=robot.ball_owner_seconds,
                          game_seconds_remaining=robot.game_seconds_remaining)
            slow = cv.detection_array(robot.detections, robot_name=session.names[i], stamp=cv.Time(sec=0), **fields)
            fast = deserialize_message(detection_array_cdr(
                robot.detections, stamp_sec=0, stamp_nanosec=0, frame_id=cv.camera_frame(session.names[i]),
                **fields), DetectionArray)
            assert field_differences(deserialize_message(serialize_message(slow), DetectionArray), fast) == []
            owners.add(fast.ball_owner)
            assert fast.game_seconds_remaining == pytest.approx(frame.snapshot.time_remaining, abs=1e-4)
    assert owners == {1, -1}
