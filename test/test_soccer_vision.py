"""Perception inside the soccer world: what each robot sees per frame, and the observation reward it earns."""
import math

import numpy as np
import pytest

from dynenv_ros.core.object_classes import ObjectClass
from dynenv_ros.envs.robocup_v0 import parallel_env
from dynenv_ros.perception.params import load_preset
from dynenv_ros.soccer.actions import SoccerAction
from dynenv_ros.soccer.rewards import observation_reward
from dynenv_ros.soccer.vision import SoccerVision
from soccer_helpers import IDLE, make_world


def _period(world, vision, actions=None):
    world.step(actions or [IDLE] * world.n_robots, on_frame=vision.frame)
    return vision.perceive()


def test_each_robot_sees_the_ball_in_front_of_it_in_every_frame_of_the_period():
    world = make_world(players_per_team=2)
    vision = SoccerVision(world, load_preset("none"))
    world.place_robot(0, -1.0, 0.0, 0.0)
    world.place_robot(2, 1.0, 0.5, math.pi)
    perception = _period(world, vision)
    n = world.n_robots
    assert len(perception) == world.config.rates.frames_per_period * n
    for frame in range(5):
        rows = perception.of_view(frame * n + 0)
        ball = rows[rows["class_id"] == ObjectClass.BALL]
        assert len(ball) == 1 and ball["x"][0] == pytest.approx(1.0, abs=1e-4) and abs(ball["y"][0]) < 1e-4
        goals = rows[rows["class_id"] == ObjectClass.GOALPOST]
        assert len(goals) == 2                                   # the opponent goal ahead, 5.5 m away
        assert np.all(np.hypot(goals["x"], goals["y"]) > 5.4)


def test_observation_reward_is_the_formula_over_what_was_truly_seen():
    world = make_world(players_per_team=2, seed=3)
    vision = SoccerVision(world, load_preset("realistic", noise_magnitude=3.0))
    world.place_robot(0, -1.0, 0.0, 0.2)
    world.place_robot(1, -2.0, 1.0, -0.3)
    world.place_robot(2, 1.0, 0.5, math.pi)
    world.place_robot(3, 2.5, -0.5, 3.0)
    perception = _period(world, vision)
    rewards = vision.observation_rewards(perception)
    n, w = world.n_robots, world.config.rewards
    seen = perception.seen.reshape(5, n, -1)
    lines = perception.lines_seen.reshape(5, n)
    landmark = vision.perceiver.is_landmark
    for robot in range(n):
        robot_frames = [int(seen[:, robot, other].sum()) for other in range(n) if other != robot]
        landmarks = (seen[:, robot, landmark].sum(axis=1) + lines[:, robot]).tolist()
        expected = observation_reward(robot_frames, landmarks, int(seen[:, robot, n].sum()), w)
        assert rewards[robot] == pytest.approx(expected)
    assert rewards.max() > 0


def test_false_positives_earn_no_observation_reward():
    params = load_preset("realistic", noise_magnitude=1.0)
    blind = {cls: type(c)(near_range=0.01, max_range=0.02) for cls, c in params.classes.items()}
    params = type(params)(**{**params.__dict__, "classes": blind,
                             "false_positives": type(params.false_positives)(probability=1.0)})
    world = make_world(players_per_team=1)
    vision = SoccerVision(world, params)
    perception = _period(world, vision)
    assert len(perception.detections) > 20 and np.all(perception.detections["true_id"] == -1)
    assert vision.observation_rewards(perception).tolist() == [0.0, 0.0]


def test_partial_observations_hold_every_frame_and_the_robots_own_head():
    env = parallel_env(players_per_team=1, perception="none", head_mode="continuous")
    env.reset(seed=0)
    turn = {"motion": np.array([0, 0, 0]), "head": np.array([0.5], np.float32)}
    obs, rewards, *_ , infos = env.step({"team_a_0": turn, "team_b_0": turn})
    o = obs["team_a_0"]
    assert len(o["detections"]) == 5
    np.testing.assert_allclose(o["proprioception"][:, 0], [0.1, 0.2, 0.3, 0.4, 0.5], atol=1e-6)
    assert infos["team_a_0"]["reward_terms"]["observation"] > 0    # lines, posts and the other robot in view
    full = parallel_env(players_per_team=1, observation="full")
    full.reset(seed=0)
    *_, infos = full.step({"team_a_0": np.array([0, 0, 0, 3]), "team_b_0": np.array([0, 0, 0, 3])})
    assert infos["team_a_0"]["reward_terms"]["observation"] == 0.0  # as in DynEnv: no look-around reward with full state


def test_image_observations_show_the_ball_ahead_in_the_ball_channel():
    env = parallel_env(players_per_team=1, observation="image", perception="none", image_size=(64, 48))
    obs, _ = env.reset(seed=0)
    images = obs["team_a_0"]["images"]
    assert images.shape == (5, 8, 48, 64) and images.dtype == np.uint8 and set(np.unique(images)) <= {0, 1}
    assert env.observation_space("team_a_0").contains(obs["team_a_0"])
    ball_top = images[0, 0]                                         # kickoff: the ball ~0.3-0.8 m ahead
    ball_bottom = images[0, 4]
    assert ball_top.sum() + ball_bottom.sum() > 0
    assert images[0, 3].sum() + images[0, 7].sum() > 0              # lines in view
