"""The scripted team on its own perception (soccer/perceiving.py): what a robot believes, from what it saw."""
from __future__ import annotations

import math

import numpy as np
import pytest

from dynenv_ros.core.object_classes import ObjectClass, ObjectStatus
from dynenv_ros.envs.padded_layout import PaddedLayout
from dynenv_ros.perception.detections import FEATURE_COLUMNS
from dynenv_ros.soccer.actions import Kick, Turn, Walk
from dynenv_ros.soccer.perceiving import (PerceivingPolicy, ball_in_view, perceiving_team, to_field)
from dynenv_ros.soccer.scripted import ChaserPolicy, GoalkeeperPolicy

PERIOD = 0.5          # s, the default motion period written out (5 frames at 10 Hz)
CLASS, X, Y, CONF = (FEATURE_COLUMNS.index(c) for c in ("class_id", "x", "y", "confidence"))


def observation(balls: dict[int, list[tuple[float, float, float]]] | None = None, head_yaw: float = 0.0,
                fallen: bool = False, owner: float = 0.0, frames: int = 5) -> dict[str, np.ndarray]:
    """One robot's padded observation with ball rows (frame → [(x, y, confidence)], camera frame)."""
    obs = {key: value[0] for key, value in PaddedLayout.for_players(2, frames).empty(1).items()}
    for frame, rows in (balls or {}).items():
        for slot, (x, y, confidence) in enumerate(rows):
            obs["objects"][frame, slot, [CLASS, X, Y, CONF]] = (ObjectClass.BALL, x, y, confidence)
            obs["object_mask"][frame, slot] = 1.0
    obs["proprioception"][:, 0] = head_yaw
    obs["proprioception"][:, 1] = float(fallen)
    obs["game"][0] = owner
    return obs


def test_the_latest_frame_and_its_most_confident_ball_are_taken_and_turned_by_the_head_yaw() -> None:
    obs = observation({1: [(1.0, 0.0, 0.9)], 3: [(2.0, 0.0, 0.3), (0.0, 1.5, 0.8)]}, head_yaw=math.pi / 2)
    frame, bx, by = ball_in_view(obs["objects"], obs["object_mask"], obs["proprioception"][:, 0])
    # frame 3 is the latest showing a ball; its most confident row is (0, 1.5) in the camera frame; the head looks
    # left by 90°, so camera +y (left of the gaze) is body -x: (0, 1.5) → (-1.5, 0)
    assert frame == 3
    assert (bx, by) == pytest.approx((-1.5, 0.0), abs=1e-6)


def test_robots_and_masked_rows_are_not_balls() -> None:
    obs = observation()
    obs["objects"][4, 0, [CLASS, X, Y, CONF]] = (ObjectClass.ROBOT, 1.0, 0.0, 1.0)
    obs["object_mask"][4, 0] = 1.0
    obs["objects"][4, 1, [CLASS, X, Y, CONF]] = (ObjectClass.BALL, 1.0, 0.0, 1.0)   # mask 0: padding
    assert ball_in_view(obs["objects"], obs["object_mask"], obs["proprioception"][:, 0]) is None


def test_body_points_go_to_the_field_through_the_pose() -> None:
    # a robot at (1, 2) facing +y sees a point 1 m ahead at (1, 3), and 1 m to its left at (0, 2)
    assert to_field((1.0, 2.0, math.pi / 2), 1.0, 0.0) == pytest.approx((1.0, 3.0))
    assert to_field((1.0, 2.0, math.pi / 2), 0.0, 1.0) == pytest.approx((0.0, 2.0))


def test_the_believed_world_has_the_estimated_pose_the_seen_ball_and_the_controllers_ownership() -> None:
    policy = PerceivingPolicy(ChaserPolicy(), robot_id=2, team=-1, period_seconds=PERIOD)
    snapshot = policy.believe(observation({4: [(1.0, 0.0, 0.9)]}, fallen=True, owner=1.0), (2.0, -1.0, math.pi))
    me, ball = snapshot.objects
    assert (me.id, me.team, me.x, me.y, me.yaw) == (2, -1, 2.0, -1.0, math.pi)
    assert me.status & ObjectStatus.FALLEN
    assert (ball.x, ball.y) == pytest.approx((1.0, -1.0))       # 1 m ahead of a robot facing -x
    assert snapshot.ball_owner_team == -1                        # "own team owns it" for team B
    assert policy.ball.age == 0.0                                # seen in the period's last frame


def test_an_unseen_ball_is_remembered_for_the_memory_then_searched_for() -> None:
    memory = 1.2
    policy = PerceivingPolicy(ChaserPolicy(), robot_id=0, team=1, period_seconds=PERIOD, memory_seconds=memory)
    policy.act(observation({0: [(1.0, 0.0, 0.9)]}), (0.0, 0.0, 0.0))
    assert policy.ball.age == pytest.approx(4 / 5 * PERIOD)      # frame 0 of 5: four fifths of a period old
    blind = observation()
    ages = []
    for _ in range(3):
        policy.act(blind, (0.0, 0.0, 0.0))
        ages.append(None if policy.ball is None else policy.ball.age)
    # 0.4 s → 0.9 → 1.4 > 1.2: forgotten in the second blind period
    assert ages[0] == pytest.approx(0.9) and ages[1] is None and ages[2] is None
    action = policy.act(blind, (0.0, 0.0, 0.0))
    assert (action.walk, action.turn, action.kick) == (Walk.NONE, Turn.LEFT, Kick.NONE)
    assert abs(action.head_yaw_delta) == pytest.approx(3 * math.radians(12.5))


def test_the_search_sweeps_the_head_back_at_its_limit() -> None:
    policy = PerceivingPolicy(ChaserPolicy(), robot_id=0, team=1, period_seconds=PERIOD)
    up = policy.act(observation(head_yaw=0.0), (0.0, 0.0, 0.0)).head_yaw_delta
    down = policy.act(observation(head_yaw=math.radians(119.0)), (0.0, 0.0, 0.0)).head_yaw_delta
    assert up > 0 > down


def test_a_chaser_with_the_ball_in_front_of_its_foot_kicks_on_what_it_saw() -> None:
    # team A attacks +x; a robot at (1, 0) facing +x with the ball 0.2 m ahead in front of its left foot: the same
    # geometry the ground-truth chaser kicks in, here known only from the detection
    from dynenv_ros.soccer.robot import FOOT_OFFSET
    policy = PerceivingPolicy(ChaserPolicy(), robot_id=1, team=1, period_seconds=PERIOD)
    action = policy.act(observation({4: [(0.20, FOOT_OFFSET, 0.9)]}), (1.0, 0.0, 0.0))
    assert action.kick == Kick.LEFT_FOOT
    # mirrored estimate (a flipped robot): it believes it faces its own goal, so it does not kick
    flipped = PerceivingPolicy(ChaserPolicy(), robot_id=1, team=1, period_seconds=PERIOD)
    assert flipped.act(observation({4: [(0.20, FOOT_OFFSET, 0.9)]}), (-1.0, 0.0, math.pi)).kick == Kick.NONE


def test_the_team_is_a_keeper_and_chasers_with_teams_by_slot() -> None:
    team = perceiving_team(2, PERIOD)
    assert [type(p.inner) for p in team] == [GoalkeeperPolicy, ChaserPolicy, GoalkeeperPolicy, ChaserPolicy]
    assert [p.team for p in team] == [1, 1, -1, -1]
    assert [type(p.inner) for p in perceiving_team(1, PERIOD)] == [ChaserPolicy, ChaserPolicy]


@pytest.mark.parametrize("kwargs, message", [({"team": 0}, "team"), ({"period_seconds": 0.0}, "period_seconds"),
                                             ({"memory_seconds": -1.0}, "memory_seconds")])
def test_bad_settings_are_refused(kwargs, message) -> None:
    settings = {"inner": ChaserPolicy(), "robot_id": 0, "team": 1, "period_seconds": PERIOD, **kwargs}
    with pytest.raises(ValueError, match=message):
        PerceivingPolicy(**settings)
