"""Self-supervised learning targets (envs/learning_targets.py) per robot: pose, ball and other robots in the team
frame, and what each robot truly saw; in the vectorised batch, the same instant as the observation, identical in
both backends. Expected values are written out from the geometry of the placed situation."""
import math

import numpy as np
import pytest

from dynenv_ros.envs.learning_targets import (BALL_COLUMNS, POSE_COLUMNS, ROBOT_COLUMNS, TARGET_KEYS, empty_targets,
                                              other_robots, target_shapes)
from dynenv_ros.envs.soccer_observations import SoccerObservations
from dynenv_ros.envs.vector import SoccerVectorEnv
from dynenv_ros.soccer.actions import SoccerAction, Turn, Walk
from dynenv_ros.soccer.world import TEAM_B
from soccer_helpers import IDLE, assert_identical, make_world

PI = math.pi
# 10 s episodes = 20 motion periods, robots fall now and then (the worlds' generators matter).
SHORT = {"players_per_team": 1, "episode_seconds": 10.0, "falls": {"p_walk": 0.05}}


def _observer(world, perception="none"):
    obs = SoccerObservations(world.config, "padded", perception)
    obs.reset(world)
    return obs


def _initial_targets(world, perception="none"):
    """Targets of the observation of the world as it stands (every frame of the period shows it)."""
    obs = _observer(world, perception)
    targets = empty_targets(world.config.players_per_team, world.n_robots)
    obs.initial_padded(targets=targets)
    return targets, obs


def _pose(x, y, yaw, head):
    return [x, y, math.cos(yaw + head), math.sin(yaw + head), math.cos(head), math.sin(head)]


def test_columns_and_order_of_the_other_robots():
    assert POSE_COLUMNS == ("x", "y", "cos_gaze", "sin_gaze", "cos_head", "sin_head")
    assert BALL_COLUMNS == ("x", "y", "owner")
    assert ROBOT_COLUMNS == ("x", "y", "cos_yaw", "sin_yaw", "teammate", "fallen")
    # teammates by index, then opponents by index; robots 0..P-1 are team A, P..2P-1 team B
    assert other_robots(1).tolist() == [[1], [0]]
    assert other_robots(2).tolist() == [[1, 2, 3], [0, 2, 3], [3, 0, 1], [2, 0, 1]]
    assert other_robots(3).tolist()[4] == [3, 5, 0, 1, 2]
    assert target_shapes(2) == {"pose": (6,), "ball": (3,), "robots": (3, 6), "ball_seen": (), "robots_seen": (3,)}


# -- (a) the robot's own pose in its team frame -------------------------------------------------------------------

def test_pose_of_a_placed_robot_in_both_team_frames():
    world = make_world(players_per_team=2)
    world.place_robot(0, -1.2, 0.7, 0.4)
    world.robots[0].head_yaw = 0.3
    world.place_robot(2, 1.5, -0.8, 2.5)
    world.robots[2].head_yaw = -0.2
    targets, _ = _initial_targets(world)
    pose = targets["pose"]
    assert pose.dtype == np.float32
    # team A: the field frame
    np.testing.assert_allclose(pose[0], _pose(-1.2, 0.7, 0.4, 0.3), atol=1e-6)
    # team B: the field frame turned by π — position negated, body yaw + π, head relative (unchanged)
    np.testing.assert_allclose(pose[2], _pose(-1.5, 0.8, 2.5 + PI, -0.2), atol=1e-6)
    np.testing.assert_allclose(pose[2], [-1.5, 0.8, -math.cos(2.3), -math.sin(2.3), math.cos(0.2), -math.sin(0.2)],
                               atol=1e-6)
    # a team B robot facing the field's -x faces the opponent goal: its gaze is +x in its frame
    world.place_robot(3, 2.0, 1.0, PI)
    targets, _ = _initial_targets(world)
    np.testing.assert_allclose(targets["pose"][3], [-2.0, -1.0, 1.0, 0.0, 1.0, 0.0], atol=1e-6)


def test_pose_is_the_one_at_the_end_of_the_period_the_observation_describes():
    world = make_world(players_per_team=1)
    world.place_robot(0, -1.0, 0.5, 0.2)
    world.place_robot(1, 1.0, -0.5, PI - 0.1)
    obs = _observer(world)
    targets = empty_targets(1, 2)
    obs.initial_padded(targets=targets)
    for _ in range(3):    # walk forward turning left, head turning right; robot 1 walks forward
        actions = [SoccerAction(Walk.FORWARD, Turn.LEFT, head_yaw_delta=-0.2), SoccerAction(Walk.FORWARD)]
        world.step(actions, on_frame=obs.on_frame)
        obs.build_padded(targets=targets)
        r0, r1 = world.robots
        np.testing.assert_allclose(targets["pose"][0], _pose(r0.x, r0.y, r0.body.angle, r0.head_yaw), atol=1e-6)
        np.testing.assert_allclose(targets["pose"][1], _pose(-r1.x, -r1.y, r1.body.angle + PI, r1.head_yaw),
                                   atol=1e-6)
    assert world.robots[0].head_yaw == pytest.approx(-0.6)
    assert targets["pose"][0, 4:].tolist() == pytest.approx([math.cos(0.6), -math.sin(0.6)], abs=1e-6)
    assert world.robots[0].x > -1.0 + 0.1       # it moved: the targets followed


# -- (b) ball and other robots --------------------------------------------------------------------------------------

def _configuration():
    world = make_world(players_per_team=2)
    world.place_robot(0, -1.0, 0.0, 0.0)
    world.place_robot(1, -2.0, 1.5, PI / 2)
    world.robots[1].rules.fallen = True
    world.place_robot(2, 1.0, 0.5, PI)
    world.place_robot(3, 2.5, -1.0, -PI / 2)
    world.place_ball(0.3, -0.4)
    world.set_ball_owner(TEAM_B, 10.0)
    return world


def test_ball_and_robots_in_both_team_frames():
    targets, obs = _initial_targets(_configuration())
    ball, robots = targets["ball"], targets["robots"]
    # team A robots: the field frame; team B owns the ball (−1 for team A)
    for i in (0, 1):
        np.testing.assert_allclose(ball[i], [0.3, -0.4, -1.0], atol=1e-6)
    np.testing.assert_allclose(robots[0], [[-2.0, 1.5, 0.0, 1.0, 1.0, 1.0],      # robot 1: teammate, fallen
                                           [1.0, 0.5, -1.0, 0.0, 0.0, 0.0],      # robot 2: opponent
                                           [2.5, -1.0, 0.0, -1.0, 0.0, 0.0]],    # robot 3: opponent
                               atol=1e-6)
    np.testing.assert_allclose(robots[1], [[-1.0, 0.0, 1.0, 0.0, 1.0, 0.0],      # robot 0
                                           [1.0, 0.5, -1.0, 0.0, 0.0, 0.0],
                                           [2.5, -1.0, 0.0, -1.0, 0.0, 0.0]], atol=1e-6)
    # team B robots: positions negated, yaws + π; its own team owns the ball (+1)
    for i in (2, 3):
        np.testing.assert_allclose(ball[i], [-0.3, 0.4, 1.0], atol=1e-6)
    np.testing.assert_allclose(robots[2], [[-2.5, 1.0, 0.0, 1.0, 1.0, 0.0],      # robot 3: teammate
                                           [1.0, 0.0, -1.0, 0.0, 0.0, 0.0],      # robot 0: facing robot 2's goal
                                           [2.0, -1.5, 0.0, -1.0, 0.0, 1.0]],    # robot 1: fallen
                               atol=1e-6)
    np.testing.assert_allclose(robots[3], [[-1.0, -0.5, 1.0, 0.0, 1.0, 0.0],     # robot 2
                                           [1.0, 0.0, -1.0, 0.0, 0.0, 0.0],
                                           [2.0, -1.5, 0.0, -1.0, 0.0, 1.0]], atol=1e-6)
    # the owner column is the observation's game[0]
    np.testing.assert_array_equal(ball[:, 2], obs.arrays["game"][:, 0])


def test_mirrored_situation_gives_team_b_what_team_a_had():
    """Point-reflect the field and swap the teams: every robot's targets are those of its counterpart."""
    first = _configuration()
    first.robots[0].head_yaw = 0.5
    second = make_world(players_per_team=2)
    swap = [2, 3, 0, 1]
    for i, j in enumerate(swap):
        r = first.robots[i]
        second.place_robot(j, -r.x, -r.y, r.body.angle + PI)
        second.robots[j].head_yaw = r.head_yaw
        second.robots[j].rules.fallen = r.rules.fallen
    bx, by = first.ball_xy
    second.place_ball(-bx, -by)
    second.set_ball_owner(-first.state.ball_owner, 10.0)
    a, _ = _initial_targets(first)
    b, _ = _initial_targets(second)
    for key in TARGET_KEYS:
        np.testing.assert_allclose(a[key], b[key][swap], atol=1e-6, err_msg=key)
    assert a["ball_seen"].any() and a["robots_seen"].any()


# -- (c) what was truly seen ----------------------------------------------------------------------------------------

def test_objects_ahead_are_seen_and_objects_behind_are_not():
    world = make_world(players_per_team=2)
    world.place_robot(0, -1.0, 0.0, 0.0)           # facing +x: the ball 1 m ahead, robot 2 2 m ahead
    world.place_robot(1, -2.5, 1.2, 0.0)           # behind robot 0
    world.place_robot(2, 1.0, 0.2, PI)             # facing −x: the ball 1 m ahead, robot 0 2 m ahead
    world.place_robot(3, 3.0, -2.0, 0.0)           # facing +x, away from everything
    world.place_ball(0.0, 0.0)
    targets, _ = _initial_targets(world)
    ball_seen, robots_seen = targets["ball_seen"], targets["robots_seen"]
    assert ball_seen.dtype == robots_seen.dtype == np.float32
    assert ball_seen[0] == 1.0 and ball_seen[2] == 1.0 and ball_seen[3] == 0.0
    # rows [1, 2, 3]: robot 1 behind; robot 2 ahead; robot 3 4.5 m away, 27° right of the gaze (view ±45°)
    assert robots_seen[0].tolist() == [0.0, 1.0, 1.0]
    assert robots_seen[2][1] == 1.0                       # rows [3, 0, 1]: robot 0 ahead
    assert robots_seen[3].tolist() == [0.0, 0.0, 0.0]


def test_seen_in_any_frame_of_the_period_counts():
    """The head turns from 37.5° to 0 over the period: the ball at a bearing of 60° from the body is in the 90°
    view in the first frames (30° and 37.5° off the gaze) and out of it at the end (60° off the gaze)."""
    world = make_world(players_per_team=1)
    world.place_robot(0, -1.0, 0.0, 0.0)
    world.place_robot(1, 3.0, 2.5, PI)
    world.place_ball(-1.0 + math.cos(math.radians(60)), math.sin(math.radians(60)))
    head = math.radians(37.5)
    world.robots[0].head_yaw = head
    obs = _observer(world)
    targets = empty_targets(1, 2)
    obs.initial_padded(targets=targets)
    assert targets["ball_seen"][0] == 1.0
    world.step([SoccerAction(head_yaw_delta=-head), IDLE], on_frame=obs.on_frame)
    obs.build_padded(targets=targets)
    assert world.robots[0].head_yaw == pytest.approx(0.0, abs=1e-12)
    assert targets["ball_seen"][0] == 1.0                 # seen in the period's first frames
    world.step([IDLE, IDLE], on_frame=obs.on_frame)
    obs.build_padded(targets=targets)
    assert targets["ball_seen"][0] == 0.0                 # not at all in the next period


# -- the batch --------------------------------------------------------------------------------------------------------

def _actions(rng, envs, robots):
    return rng.integers([0, 0, 0, 0], [5, 3, 3, 7], size=(envs, robots, 4))


def _rollout(backend, steps, targets=True, envs=3, seed=11):
    rng = np.random.default_rng(5)
    with SoccerVectorEnv(envs, backend=backend, workers=2, config=SHORT, targets=targets) as env:
        out = [(env.reset(seed=seed), env.targets if targets else None)]
        for _ in range(steps):
            result = env.step(_actions(rng, envs, 2))
            out.append((result.observations, result.targets, result.final_targets, result.final_observations,
                        result.rewards, result.terminated, result.truncated))
            if targets:
                assert_identical(env.targets, result.targets)
    return out


def test_backends_give_bit_identical_targets_across_an_episode_end():
    a = _rollout("inprocess", 30)
    b = _rollout("subprocess", 30)       # 2 workers: worlds 0-1 and 2
    assert_identical(a, b)
    ends = [k for k, step in enumerate(a[1:]) if step[6].any()]
    assert ends == [19]
    assert sorted(a[20][2]) == [0, 1, 2]                  # final targets of every world
    assert any(step[1]["ball_seen"].any() and step[1]["robots_seen"].any() for step in a[1:])


def test_targets_leave_the_observations_and_rewards_unchanged():
    with_targets = _rollout("inprocess", 25)
    without = _rollout("inprocess", 25, targets=False)
    assert_identical([with_targets[0][0]] + [s[0] for s in with_targets[1:]],
                      [without[0][0]] + [s[0] for s in without[1:]])
    assert_identical([s[3:] for s in with_targets[1:]], [s[3:] for s in without[1:]])
    assert all(s[1] is None and s[2] == {} for s in without[1:])


def _by_hand(world):
    """(A, 6) poses and (A, 3) ball targets read from the world's bodies: x, y, heading turned by π for team B."""
    poses, balls = [], []
    bx, by = world.ball_xy
    for r in world.robots:
        t = r.team
        gaze = r.body.angle + r.head_yaw + (0.0 if t > 0 else PI)
        poses.append([t * r.x, t * r.y, math.cos(gaze), math.sin(gaze), math.cos(r.head_yaw),
                      math.sin(r.head_yaw)])
        balls.append([t * bx, t * by, t * world.state.ball_owner])
    return np.array(poses), np.array(balls)


def test_batch_targets_are_the_worlds_state_when_the_observation_is_made_reset_included():
    rng = np.random.default_rng(2)
    with SoccerVectorEnv(2, backend="inprocess", config=SHORT, targets=True) as env:
        obs = env.reset(seed=4)
        worlds = env._batch.worlds
        for step in range(25):
            targets = env.targets
            for e, world in enumerate(worlds):
                pose, ball = _by_hand(world)
                np.testing.assert_allclose(targets["pose"][e], pose, atol=1e-5)
                np.testing.assert_allclose(targets["ball"][e], ball, atol=1e-5)
                np.testing.assert_array_equal(targets["ball"][e, :, 2], obs["game"][e, :, 0])
            if step == 20:     # the episode ended at step 20: the world was reset, the targets show it
                assert world.period == 0
                np.testing.assert_allclose(targets["ball"][:, :, :2], 0.0, atol=1e-6)
            result = env.step(_actions(rng, 2, 2))
            obs = result.observations
            assert result.truncated.any() == (step == 19)


# -- (e) shapes, dtypes, refusals --------------------------------------------------------------------------------------

def test_shapes_dtypes_and_refusals():
    with SoccerVectorEnv(2, backend="inprocess", config={"players_per_team": 2}, targets=True) as env:
        with pytest.raises(RuntimeError, match="reset"):
            _ = env.targets
        env.reset(seed=3)
        result = env.step(np.zeros((2, 4, 4), int))
        expected = {"pose": (2, 4, 6), "ball": (2, 4, 3), "robots": (2, 4, 3, 6), "ball_seen": (2, 4),
                    "robots_seen": (2, 4, 3)}
        assert env.with_targets and env.target_shapes == target_shapes(2)
        for batch in (env.targets, result.targets):
            assert list(batch) == list(TARGET_KEYS)
            for key, value in batch.items():
                assert value.shape == expected[key] and value.dtype == np.float32
            for key in ("ball_seen", "robots_seen"):
                assert set(np.unique(batch[key])) <= {0.0, 1.0}
            assert set(np.unique(batch["robots"][..., 4:])) <= {0.0, 1.0}
            np.testing.assert_array_equal(batch["robots"][..., 4].sum(axis=-1), 1.0)   # one teammate in 2v2
        returned = result.targets["pose"]
        returned[...] = 99.0                                  # a copy: the env's arrays are untouched
        assert not (env.targets["pose"] == 99.0).any()
    with SoccerVectorEnv(1, backend="inprocess") as env:
        env.reset(seed=0)
        assert not env.with_targets and env.target_shapes is None
        assert env.step(np.zeros((1, 4, 4), int)).targets is None
        with pytest.raises(RuntimeError, match="targets=True"):
            _ = env.targets
    with pytest.raises(ValueError, match="padded"):
        SoccerVectorEnv(1, backend="inprocess", observation="full", targets=True)
