"""The fast DetectionArray serialiser gives messages rclpy reads back field for field, for every head length."""
import numpy as np
import pytest
from rclpy.serialization import deserialize_message

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
                  fallen=True, penalized=False)
    stamp = cv.Time(sec=12, nanosec=345_000_000)
    slow = cv.detection_array(rows, robot_name=frame_id.split("/")[0], stamp=stamp, **fields)
    slow.header.frame_id = frame_id
    fast = deserialize_message(detection_array_cdr(rows, stamp_sec=12, stamp_nanosec=345_000_000,
                                                   frame_id=frame_id, **fields), DetectionArray)
    assert field_differences(slow, fast) == []
