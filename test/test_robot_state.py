"""The robot's own state in the reverse adapter's frames (dynenv_ros/ros/robot_state.py): head yaw from JointState
at the frame's moment, fallen / penalized / GameController values while fresh, defaults (counted) otherwise."""
from __future__ import annotations

import math
from types import SimpleNamespace

from dynenv_ros.ros.robot_state import DEFAULTS, FALLEN, GAME_STATE, PENALIZED, RobotState, game_problem

MS = 1_000_000


def _joint_state(stamp_ns: int, yaw: float, name: str = "HeadYaw"):
    stamp = SimpleNamespace(sec=stamp_ns // 10**9, nanosec=stamp_ns % 10**9)
    return SimpleNamespace(header=SimpleNamespace(stamp=stamp), name=["HeadPitch", name], position=[0.3, yaw])


def _frame():
    return SimpleNamespace(head_yaw=None, self_fallen=None, self_penalized=None, ball_owner=None,
                           ball_owner_seconds=None, game_seconds_remaining=None)


def test_nothing_published_gives_the_defaults_counted_as_missing():
    state, frame = RobotState(), _frame()
    state.fill(frame, 5 * 10**9, 5 * 10**9)
    assert (frame.head_yaw, frame.self_fallen, frame.self_penalized) == (0.0, False, False)
    assert (frame.ball_owner, frame.ball_owner_seconds, frame.game_seconds_remaining) == DEFAULTS[GAME_STATE]
    assert state.counts == {"head_yaw_missing": 1, "fallen_missing": 1, "penalized_missing": 1,
                            "game_state_missing": 1}


def test_head_yaw_is_the_sample_nearest_the_frames_stamp():
    state = RobotState(head_yaw_max_age_s=0.1)
    for k in range(10):                                    # 100 Hz, out of order once
        state.joint_state(_joint_state(1000 * MS + (9 - k if k == 3 else k) * 10 * MS, 0.01 * k), 0)
    assert math.isclose(state.head_yaw(1041 * MS), 0.04)   # sample at 1040 ms
    assert state.head_yaw(1300 * MS) == 0.0               # 210 ms after the newest: stale
    state.joint_state(_joint_state(2000 * MS, 0.5, name="LShoulderPitch"), 0)    # no head joint: ignored
    assert state.counts == {"head_yaw_used": 1, "head_yaw_stale": 1}


def test_flags_and_game_state_are_used_while_fresh():
    state = RobotState(state_max_age_s=1.0)
    state.flag(FALLEN, SimpleNamespace(data=True), 10 * 10**9)
    state.flag(PENALIZED, SimpleNamespace(data=True), 9 * 10**9)
    assert state.game_state(SimpleNamespace(data=[-1.0, 8.5, 290.0]), 10 * 10**9) == ""
    frame = _frame()
    state.fill(frame, 10_500 * MS, 10_500 * MS)
    assert (frame.self_fallen, frame.self_penalized) == (True, False)     # penalized: 1.5 s old, stale
    assert (frame.ball_owner, frame.ball_owner_seconds, frame.game_seconds_remaining) == (-1, 8.5, 290.0)
    assert state.counts[f"{FALLEN}_used"] == 1 and state.counts[f"{PENALIZED}_stale"] == 1
    assert state.counts[f"{GAME_STATE}_used"] == 1


def test_a_malformed_game_state_is_refused_with_the_reason():
    assert "expected 3" in game_problem([1.0, 2.0])
    assert "non-finite" in game_problem([0.0, float("nan"), 1.0])
    assert "ball_owner" in game_problem([2.0, 0.0, 1.0])
    assert "negative" in game_problem([1.0, -1.0, 1.0])
    state = RobotState()
    assert "ball_owner" in state.game_state(SimpleNamespace(data=[0.5, 0.0, 1.0]), 0)
    assert state.counts == {"state_malformed": 1} and GAME_STATE not in state.latest
