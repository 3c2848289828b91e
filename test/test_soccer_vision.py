"""Perception inside the soccer world: what each robot sees per frame, and the observation reward it earns."""
import math

import numpy as np
import pytest

from dynenv_ros.core.object_classes import ObjectClass
from dynenv_ros.envs.robocup_v0 import parallel_env
from dynenv_ros.perception.detections import empty
from dynenv_ros.perception.model import Perception
from dynenv_ros.perception.params import load_preset
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


# docs/soccer.md, observation term (docs/original.md §6.1, the same weights and caps), per robot and motion period:
# 0.0025·(R + L) + 0.01·B, R = Σ over the other robots of min(2, frames it was seen), L = landmarks seen per frame
# (posts, penalty marks, line crossings, field lines: SoccerVision.landmarks_seen) averaged over the frames, capped
# at 3, B = min(3, frames the real ball was seen).
LANDMARK_CLASSES = (ObjectClass.GOALPOST, ObjectClass.PENALTY_CROSS, ObjectClass.LINE_CROSSING)


def _expected_observation_reward(seen, lines_seen, classes, robot, n):
    """seen (frames, observers, objects) bool, lines_seen (frames, observers): the documented formula, by hand."""
    frames = seen.shape[0]
    r_term = 0
    for other in range(n):
        if other != robot:
            r_term += min(2, sum(bool(seen[f, robot, other]) for f in range(frames)))
    per_frame = [sum(bool(seen[f, robot, j]) for j in range(len(classes)) if classes[j] in LANDMARK_CLASSES)
                 + int(lines_seen[f, robot]) for f in range(frames)]
    l_term = min(3.0, sum(per_frame) / frames)
    b_term = min(3, sum(bool(seen[f, robot, n]) for f in range(frames)))       # the ball is scene object n
    return 0.0025 * (r_term + l_term) + 0.01 * b_term, (r_term, l_term, b_term)


def test_observation_reward_is_the_formula_over_what_was_truly_seen():
    world = make_world(players_per_team=2, seed=3)
    vision = SoccerVision(world, load_preset("realistic", noise_magnitude=3.0))
    world.place_robot(0, -1.0, 0.0, 0.2)
    world.place_robot(1, -2.0, 1.0, -0.3)
    world.place_robot(2, 1.0, 0.5, math.pi)
    world.place_robot(3, 0.0, -3.3, -0.5)           # just off the sideline looking out: few landmarks, no ball
    perception = _period(world, vision)
    rewards = vision.observation_rewards(perception)
    n = world.n_robots
    seen = perception.seen.reshape(5, n, -1)
    lines = perception.lines_seen.reshape(5, n)
    classes = vision.objects.class_id.tolist()
    terms = []
    for robot in range(n):
        expected, parts = _expected_observation_reward(seen, lines, classes, robot, n)
        terms.append(parts)
        assert rewards[robot] == pytest.approx(expected, abs=1e-12)
    # the scene exercises each part below and beyond its cap (R: 2 frames per robot, L: 3, B: 3 frames)
    assert any(0 < lt < 3 for _, lt, _ in terms) and any(lt == 3 for _, lt, _ in terms)
    assert any(b == 0 for _, _, b in terms) and (seen[:, :, n].sum(axis=0) > 3).any()
    assert any(r == 0 for r, _, _ in terms) and (seen[:, :, :n].sum(axis=0) > 2).any()


def test_observation_reward_of_hand_made_sightings_has_the_documented_value():
    """Sightings set by hand (1v1, five frames), expected rewards worked out on paper."""
    world = make_world(players_per_team=1)
    vision = SoccerVision(world, load_preset("none"))
    classes = vision.objects.class_id
    n, frames, objects = 2, 5, len(classes)
    post, mark, crossing, circle = (int(np.flatnonzero(classes == c)[0]) for c in (
        ObjectClass.GOALPOST, ObjectClass.PENALTY_CROSS, ObjectClass.LINE_CROSSING, ObjectClass.CENTER_CIRCLE))
    seen = np.zeros((frames, n, objects), bool)
    lines = np.zeros((frames, n), np.int64)
    # robot 0: robot 1 in 3 frames (capped at 2), the ball in all 5 (capped at 3), 2 posts + 3 lines in frame 0
    # and 4 landmarks in each other frame: mean 4.2, capped at 3 → 0.0025·(2 + 3) + 0.01·3 = 0.0425
    seen[0:3, 0, 1] = True
    seen[:, 0, n] = True
    seen[0, 0, post:post + 2] = True
    lines[0, 0] = 3
    seen[1:, 0, crossing:crossing + 4] = True
    seen[:, 0, 0] = True                               # R sums over the OTHER robots: oneself never counts
    # robot 1: robot 0 in 1 frame, the ball in 2, a crossing in frame 0, a mark and a line in frame 1: mean 0.6;
    # the centre circle in every frame is not one of the counted landmarks → 0.0025·(1 + 0.6) + 0.01·2 = 0.024
    seen[4, 1, 0] = True
    seen[[1, 3], 1, n] = True
    seen[0, 1, crossing] = True
    seen[1, 1, mark] = True
    lines[1, 1] = 1
    seen[:, 1, circle] = True
    perception = Perception(detections=empty(0), offsets=np.zeros(frames * n + 1, np.int64),
                            seen=seen.reshape(frames * n, objects), lines_seen=lines.reshape(frames * n),
                            visible=seen.reshape(frames * n, objects))
    assert vision.observation_rewards(perception).tolist() == pytest.approx([0.0425, 0.024], abs=1e-12)


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
    # Declared as an image (uint8 0/255, channels first: 8 per frame, 4 per camera) so image-aware tools use it.
    space = env.observation_space("team_a_0")["images"]
    assert space.shape == (5 * 8, 48, 64) and space.dtype == np.uint8 and (space.low == 0).all()
    assert (space.high == 255).all()
    assert images.shape == (40, 48, 64) and images.dtype == np.uint8 and set(np.unique(images)) <= {0, 255}
    assert env.observation_space("team_a_0").contains(obs["team_a_0"])
    frame = 0
    ball_top = images[8 * frame + 0]                                # kickoff: the ball ~0.3-0.8 m ahead
    ball_bottom = images[8 * frame + 4]
    assert ball_top.sum() + ball_bottom.sum() > 0
    assert images[8 * frame + 3].sum() + images[8 * frame + 7].sum() > 0     # lines in view
