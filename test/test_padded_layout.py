"""The fixed-shape observation: one definition, the same arrays from the env, the variable-length rows, the policy
node's messages and the agent's input adapter (issue 10, "A fixed-shape observation every RL tool can batch")."""
from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from rclpy.time import Time

from dynenv_ros.envs.padded_layout import KEYS, PaddedLayout, pack_frames
from dynenv_ros.envs.robocup_v0 import parallel_env
from dynenv_ros.envs.soccer_observations import SoccerObservations
from dynenv_ros.ros.conversions import detection_array
from dynenv_ros.soccer.config import SoccerConfig
from dynenv_ros.soccer.world import SoccerWorld
from dynenv_ros.agent.inputs import collate, side_inputs, streams_from_padded
from dynenv_ros.envs.detection_messages import pack_messages

HEAD_STEP = math.radians(12.5)          # docs/soccer.md: head index 0..6, 12.5° per unit, centred on 3
LANDMARK_IDS, OBJECT_IDS = (3, 4, 5, 6, 7), (1, 2)


def _play(observation: str, steps: int, seed: int = 5, **settings):
    env = parallel_env(players_per_team=2, observation=observation, **settings)
    obs, _ = env.reset(seed=seed)
    rng = np.random.default_rng(seed)
    history, actions_given = [obs], []
    for _ in range(steps):
        actions = {a: np.array([rng.integers(5), rng.integers(3), rng.integers(3), rng.integers(7)])
                   for a in env.agents}
        obs, _, _, _, infos = env.step(actions)
        history.append(obs)
        actions_given.append(actions)
    return env, history, actions_given


def test_padded_observations_are_the_variable_length_rows_packed_for_the_same_seed():
    env, padded, actions = _play("padded", 25)
    _, partial, _ = _play("partial", 25)
    agents = env.possible_agents
    layout = env.observations.layout
    for step, (p, q) in enumerate(zip(padded, partial)):
        packed, dropped = pack_frames(layout, [list(q[a]["detections"]) for a in agents])
        assert dropped.sum() == 0
        for key in ("landmarks", "landmark_mask", "objects", "object_mask"):
            np.testing.assert_array_equal(packed[key], np.stack([p[a][key] for a in agents]), err_msg=key)
        for a in agents:
            np.testing.assert_array_equal(p[a]["proprioception"], q[a]["proprioception"])
            np.testing.assert_array_equal(p[a]["game"], q[a]["game"])
            expected = (np.zeros(4) if step == 0 else
                        [*actions[step - 1][a][:3], (actions[step - 1][a][3] - 3) * HEAD_STEP])
            np.testing.assert_allclose(p[a]["previous_action"], expected, rtol=0, atol=1e-6)
            assert env.observation_space(a).contains(p[a])


def test_rows_sit_in_their_stream_nearest_first_and_masks_mark_exactly_the_rows():
    env, padded, _ = _play("padded", 10)
    for obs in padded[1:]:
        for o in obs.values():
            for rows_key, mask_key, classes in (("landmarks", "landmark_mask", LANDMARK_IDS),
                                                ("objects", "object_mask", OBJECT_IDS)):
                rows, mask = o[rows_key], o[mask_key]
                assert set(np.unique(mask)) <= {0.0, 1.0}
                assert np.isin(rows[..., 0][mask == 1], classes).all()
                assert (rows[mask == 0] == 0).all()
                # valid rows first, then padding, and nearest first within a frame
                assert (np.diff(mask, axis=-1) <= 0).all()
                d = np.hypot(rows[..., 1], rows[..., 2])
                valid_pairs = (mask[..., 1:] == 1)
                assert (np.diff(d, axis=-1)[valid_pairs] >= -1e-6).all()


def test_rows_beyond_the_maxima_are_dropped_farthest_first_and_counted():
    env, padded, _ = _play("padded", 8, max_landmarks=3, max_objects=1)
    _, partial, _ = _play("partial", 8)
    agents = env.possible_agents
    assert env.observation_space(agents[0])["landmarks"].shape == (5, 3, 19)
    dropped_total = 0
    for p, q in zip(padded[1:], partial[1:]):
        for a in agents:
            for k, rows in enumerate(q[a]["detections"]):
                landmarks = rows[np.isin(rows[:, 0], LANDMARK_IDS)]
                objects = rows[np.isin(rows[:, 0], OBJECT_IDS)]
                np.testing.assert_array_equal(p[a]["landmarks"][k][:len(landmarks)], landmarks[:3])
                np.testing.assert_array_equal(p[a]["objects"][k][:len(objects)], objects[:1])
                dropped_total += max(0, len(landmarks) - 3) + max(0, len(objects) - 1)
    assert dropped_total > 0


def test_dropped_detections_are_reported_in_the_infos():
    env = parallel_env(players_per_team=2, observation="padded", max_landmarks=2)
    env.reset(seed=1)
    _, _, _, _, infos = env.step({a: np.array([0, 0, 0, 3]) for a in env.agents})
    assert all(info["dropped_detections"] > 0 for info in infos.values())


def test_game_state_is_what_the_game_controller_says_at_kick_off():
    """docs/soccer.md: team A kicks off and owns the ball for 10 s; an episode is 120 s."""
    env = parallel_env(players_per_team=2, observation="padded")
    obs, _ = env.reset(seed=0)
    np.testing.assert_allclose(obs["team_a_0"]["game"], [1.0, 10.0, 120.0], atol=1e-5)
    np.testing.assert_allclose(obs["team_b_1"]["game"], [-1.0, 10.0, 120.0], atol=1e-5)
    obs, *_ = env.step({a: np.array([0, 0, 0, 3]) for a in env.agents})
    np.testing.assert_allclose(obs["team_a_1"]["game"], [1.0, 9.5, 119.5], atol=1e-5)


def test_the_layout_declares_float32_boxes_with_the_documented_shapes():
    layout = PaddedLayout.for_players(3, frames=5)
    space = layout.space()
    assert set(space.spaces) == set(KEYS)
    assert {k: s.shape for k, s in space.spaces.items()} == {
        "landmarks": (5, 40, 19), "landmark_mask": (5, 40), "objects": (5, 10, 19), "object_mask": (5, 10),
        "proprioception": (5, 4), "game": (3,), "previous_action": (4,)}
    assert all(s.dtype == np.float32 for s in space.spaces.values())
    with pytest.raises(ValueError, match="max_objects"):
        PaddedLayout(5, 32, 0)


def test_the_agent_adapter_reads_the_padded_arrays_as_collate_reads_the_rows():
    env, padded, _ = _play("padded", 4)
    _, partial, _ = _play("partial", 4)
    agents = env.possible_agents
    batch = {k: np.stack([padded[-1][a][k] for a in agents]) for k in KEYS}
    landmarks, objects = streams_from_padded(batch)
    layout = env.observations.layout
    ref_l, ref_o = collate([partial[-1][a]["detections"] for a in agents], layout.max_landmarks, layout.max_objects)
    for got, ref in ((landmarks, ref_l), (objects, ref_o)):
        assert torch.equal(got.features, ref.features) and torch.equal(got.mask, ref.mask)
        assert torch.equal(got.kind, ref.kind)
        assert (got.kind[~got.mask] > 0).all() and (got.kind[got.mask] == 0).all()
    previous, state = side_inputs(batch, head_max=3 * HEAD_STEP)
    assert previous.shape == (4, 12) and state.shape == (4, 7)


def test_the_policy_node_packs_its_messages_into_the_same_arrays():
    """The ROS path: DetectionArray messages of a period → ``pack_messages`` → the env's arrays."""
    config = SoccerConfig.from_mapping({"players_per_team": 2})
    world = SoccerWorld(config, seed=3)
    observations = SoccerObservations(config, "padded", "realistic")
    observations.reset(world)
    rng = np.random.default_rng(3)
    for _ in range(6):
        world.step([[rng.integers(5), rng.integers(3), rng.integers(3), rng.integers(7)] for _ in range(4)],
                   on_frame=observations.on_frame)
        observations.build_padded()
    # One more period: both paths from one perception.
    world.step([[0, 0, 0, 3]] * 4, on_frame=observations.on_frame)
    vision = observations.vision
    perception = vision.perceive()
    expected = observations._pack(perception)
    n, frames = 4, len(perception) // 4
    periods = []
    for i in range(n):
        msgs = []
        for k in range(frames):
            proprio, game = vision.proprioception[k, i], vision.game_controller[k, i]
            msgs.append(detection_array(
                perception.of_view(k * n + i), robot_id=i, robot_name=config.robot_names[i], episode_id=1,
                motion_period=7, frame_index=k, frames_per_period=frames, head_yaw=float(proprio[0]),
                fallen=bool(proprio[1]), penalized=bool(proprio[2]), kicking=bool(proprio[3]),
                ball_owner=int(game[0]), ball_owner_seconds=float(game[1]), game_seconds_remaining=float(game[2]),
                stamp=Time(seconds=1)))
        periods.append(msgs)
    layout = observations.layout
    got, dropped = pack_messages(periods, [tuple(expected["previous_action"][i]) for i in range(n)],
                                 layout.max_landmarks, layout.max_objects)
    assert dropped == 0
    for key in KEYS:
        np.testing.assert_allclose(got[key], expected[key], rtol=0, atol=1e-6, err_msg=key)


@pytest.mark.parametrize("settings,message", [({"max_landmarks": 0}, "max_landmarks"),
                                              ({"max_objects": "x"}, "max_objects"),
                                              ({"max_objects": 2.5}, "max_objects"),
                                              ({"observation": "ragged"}, "observation")])
def test_bad_layout_settings_are_refused_by_name(settings, message):
    with pytest.raises(ValueError, match=message):
        parallel_env(**{"observation": "padded", **settings})
