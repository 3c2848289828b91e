"""driving_v0(observation="padded"): partial's rows in the one padded layout (envs.padded_layout, driving's spec)."""
import numpy as np
import pytest
from pettingzoo.test import parallel_api_test, parallel_seed_test

from dynenv_ros.core.object_classes import ObjectClass
from dynenv_ros.envs.driving_observations import default_maxima, driving_layout
from dynenv_ros.driving.config import DrivingConfig
from dynenv_ros.envs.driving_v0 import parallel_env
from dynenv_ros.envs.padded_layout import PaddedLayout, pack_frames

SHORT = {"episode_seconds": 5.0, "pedestrians": {"count_min": 3, "count_max": 5},
         "obstacles": {"count_min": 2, "count_max": 4}}
LANE_IDS = (int(ObjectClass.SELF), int(ObjectClass.LANE))
OBJECT_IDS = (int(ObjectClass.CAR), int(ObjectClass.PEDESTRIAN), int(ObjectClass.OBSTACLE), int(ObjectClass.UNKNOWN))


def _play(observation, steps, seed=4, **settings):
    env = parallel_env(observation=observation, **settings)
    obs, infos = env.reset(seed=seed)
    for i, agent in enumerate(env.possible_agents):
        env.action_space(agent).seed(seed + i)
    history, info_history = [obs], [infos]
    for _ in range(steps):
        if not env.agents:
            break
        obs, _, _, _, infos = env.step({a: env.action_space(a).sample() for a in env.agents})
        history.append(obs)
        info_history.append(infos)
    return env, history, info_history


@pytest.mark.parametrize("action_mode", ["discrete", "continuous"])
def test_padded_is_partial_packed_for_the_same_seed(action_mode):
    env, padded, _ = _play("padded", 40, n_cars=3, action_mode=action_mode)
    _, partial, _ = _play("partial", 40, n_cars=3, action_mode=action_mode)
    layout = env.observations.layout
    assert len(padded) == len(partial) > 1
    for p, q in zip(padded, partial):
        assert p.keys() == q.keys()
        for agent in p:
            packed, dropped = pack_frames(layout, [list(q[agent]["detections"])])
            assert dropped.sum() == 0
            for key in ("lanes", "lane_mask", "objects", "object_mask"):
                np.testing.assert_array_equal(packed[key][0], p[agent][key], err_msg=key)
            # every row of partial's frame sits in one of the two streams
            rows = q[agent]["detections"][0]
            assert p[agent]["lane_mask"].sum() + p[agent]["object_mask"].sum() == len(rows)
            np.testing.assert_array_equal(p[agent]["proprioception"], q[agent]["ego"])
            np.testing.assert_array_equal(p[agent]["previous_action"], q[agent]["previous_action"])
            assert env.observation_space(agent).contains(p[agent])


def test_streams_self_row_first_then_nearest_and_the_clock():
    env, padded, _ = _play("padded", 20, n_cars=2)
    config = env.config
    for t, obs in enumerate(padded):
        for o in obs.values():
            assert o["lanes"][0, 0, 0] == ObjectClass.SELF and o["lane_mask"][0, 0] == 1
            for rows_key, mask_key, classes in (("lanes", "lane_mask", LANE_IDS), ("objects", "object_mask",
                                                                                   OBJECT_IDS)):
                rows, mask = o[rows_key], o[mask_key]
                assert np.isin(rows[..., 0][mask == 1], classes).all()
                assert (rows[mask == 0] == 0).all() and (np.diff(mask, axis=-1) <= 0).all()
                d = np.hypot(rows[..., 1], rows[..., 2])
                first = 1 if rows_key == "lanes" else 0          # the SELF row (its destination) leads
                valid = mask[..., first + 1:] == 1
                assert (np.diff(d[..., first:], axis=-1)[valid] >= -1e-4).all()
            np.testing.assert_allclose(o["game"], [config.episode_seconds - t * config.period_seconds], atol=1e-4)


def test_the_layout_shapes_and_defaults():
    config = DrivingConfig(n_cars=2)
    layout = driving_layout(config)
    assert default_maxima(config) == (11, 52) and default_maxima(DrivingConfig(n_cars=10)) == (11, 68)
    assert layout.shapes() == {"lanes": (1, 11, 19), "lane_mask": (1, 11), "objects": (1, 52, 19),
                               "object_mask": (1, 52), "proprioception": (1, 8), "game": (1,),
                               "previous_action": (3,)}
    space = layout.space()
    assert set(space.spaces) == set(layout.keys) and all(s.dtype == np.float32 for s in space.spaces.values())
    np.testing.assert_allclose(space["previous_action"].high, [1.0, 1.0, config.cars.max_yaw_rate], rtol=1e-6)
    assert space["game"].high[0] == 60.0
    with pytest.raises(ValueError, match="head_max"):
        layout.space(head_max=1.0)
    # a fixed-shape runtime's layout from variable rows reads the spec too
    fitted = PaddedLayout.fitting([[np.array([[24] + [0] * 18, [20] + [0] * 18], np.float32)]], spec=layout.spec)
    assert fitted.maxima == (1, 1) and fitted.keys == layout.keys


def test_rows_beyond_the_maxima_are_dropped_farthest_first_and_counted():
    env, padded, infos = _play("padded", 10, n_cars=2, observation_options={"max_lanes": 3, "max_objects": 2})
    _, partial, _ = _play("partial", 10, n_cars=2)
    assert env.observation_space("car_0")["objects"].shape == (1, 2, 19)
    dropped = 0
    for p, q, info in zip(padded, partial, infos):
        for agent in p:
            rows = q[agent]["detections"][0]
            lanes, objects = rows[np.isin(rows[:, 0], LANE_IDS)], rows[np.isin(rows[:, 0], OBJECT_IDS)]
            np.testing.assert_array_equal(p[agent]["lanes"][0][:len(lanes)], lanes[:3])
            np.testing.assert_array_equal(p[agent]["objects"][0][:len(objects)], objects[:2])
            expected = max(0, len(lanes) - 3) + max(0, len(objects) - 2)
            assert info[agent]["dropped_detections"] == expected
            dropped += expected
    assert dropped > 0


@pytest.mark.parametrize("settings", [{"n_cars": 2, **SHORT}, {"n_cars": 3, "action_mode": "continuous", **SHORT}])
def test_padded_passes_pettingzoo_parallel_api_and_seed_tests(settings):
    with pytest.warns(UserWarning, match="unknown option"):    # the API test passes a dummy reset option
        parallel_api_test(parallel_env(observation="padded", **settings), num_cycles=60)
    parallel_seed_test(lambda: parallel_env(observation="padded", **settings))
