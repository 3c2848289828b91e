"""driving_v0's perceived observation mode 'partial' (envs/driving_observations.py)."""
import numpy as np
import pytest
from pettingzoo.test import parallel_api_test, parallel_seed_test

from dynenv_ros.core.object_classes import ObjectClass
from dynenv_ros.envs.driving_observations import feature_bound
from dynenv_ros.envs.driving_v0 import parallel_env
from dynenv_ros.perception.detections import FEATURE_COLUMNS
from dynenv_ros.perception.driving_model import EGO_COLUMNS

SHORT = {"episode_seconds": 6.0}
F = {name: i for i, name in enumerate(FEATURE_COLUMNS)}


@pytest.mark.parametrize("perception", ["realistic", "none"])
def test_partial_passes_pettingzoo_parallel_api_test(perception):
    env = parallel_env(n_cars=3, teams=2, observation="partial", perception=perception, **SHORT)
    with pytest.warns(UserWarning, match="unknown option"):
        parallel_api_test(env, num_cycles=60)


def test_partial_passes_pettingzoo_seed_test():
    parallel_seed_test(lambda: parallel_env(n_cars=3, observation="partial", **SHORT))


def _rollout(seed, **settings):
    env = parallel_env(**settings)
    obs, infos = env.reset(seed=seed)
    for agent in env.possible_agents:
        env.action_space(agent).seed(seed)
    trace = [(obs, infos)]
    while env.agents:
        obs, _, _, _, infos = env.step({a: env.action_space(a).sample() for a in env.agents})
        trace.append((obs, infos))
    return trace, env


def test_partial_observations_lie_in_the_space_and_repeat_with_the_seed():
    a, env = _rollout(5, n_cars=4, teams=2, observation="partial", perception="realistic", **SHORT)
    b, _ = _rollout(5, n_cars=4, teams=2, observation="partial", perception="realistic", **SHORT)
    space = env.observation_space("car_0")
    rows = 0
    for (oa, ia), (ob, _ib) in zip(a, b):
        for agent, o in oa.items():
            assert space.contains(o), agent
            (det,) = o["detections"]
            assert det.dtype == np.float32 and det.shape[1] == len(FEATURE_COLUMNS)
            assert det[0, F["class_id"]] == ObjectClass.SELF                  # the SELF row first
            np.testing.assert_array_equal(det[0, [F["x"], F["y"]]], o["ego"][0, 2:4])  # its goal = the ego goal
            rows += len(det)
            np.testing.assert_array_equal(det, ob[agent]["detections"][0])
            np.testing.assert_array_equal(o["ego"], ob[agent]["ego"])
            assert ia[agent]["seen_objects"] <= ia[agent]["visible_objects"]
            assert ia[agent]["reward_terms"]["observation"] == 0.0
    assert rows > 10 * len(a)
    assert len(a) == len(b)


def test_partial_previous_action_is_the_last_command():
    env = parallel_env(n_cars=2, observation="partial", perception="none")
    env.reset(seed=1)
    obs, *_ = env.step({"car_0": np.array([2, 0]), "car_1": np.array([1, 2])})
    w = env.config.cars.max_yaw_rate
    np.testing.assert_allclose(obs["car_0"]["previous_action"], [1.0, 0.0, -w], rtol=1e-6)
    np.testing.assert_allclose(obs["car_1"]["previous_action"], [0.0, 1.0, w], rtol=1e-6)


def test_perception_none_reports_the_full_observations_ground_truth():
    """Two independent paths (the perception model's rows, the full mode's ground-truth encoder), one seed: every
    car, pedestrian and obstacle row of 'partial' with perception='none' is a body of 'full' at the same place, with
    the same heading, size and team; the SELF row is the full observation's goal, speed and outline."""
    from dynenv_ros.envs.driving_observations import FullLayout
    settings = {"n_cars": 4, "teams": 2, "episode_seconds": 8.0}
    partial, _ = _rollout(2, observation="partial", perception="none", **settings)
    full, env = _rollout(2, observation="full", **settings)
    layout = FullLayout.for_config(env.config)
    assert len(partial) == len(full)
    matched = {ObjectClass.CAR: 0, ObjectClass.PEDESTRIAN: 0, ObjectClass.OBSTACLE: 0}
    for (po, _), (fo, _) in zip(partial, full):
        assert po.keys() == fo.keys()
        for agent in po:
            (det,) = po[agent]["detections"]
            parts = layout.split(fo[agent])
            me = parts["self"]
            assert det[0, F["class_id"]] == ObjectClass.SELF
            np.testing.assert_allclose(det[0, [F["x"], F["y"]]], me[9:11], atol=1e-4)         # goal
            np.testing.assert_allclose(det[0, F["line_start_x"]], me[4], atol=1e-4)           # speed
            np.testing.assert_allclose(det[0, [F["size_x"], F["size_y"]]], me[7:9], atol=1e-5)
            np.testing.assert_array_equal(po[agent]["ego"][0, [EGO_COLUMNS.index("crashed"),
                                                              EGO_COLUMNS.index("finished")]], me[[12, 11]])
            tables = {ObjectClass.CAR: (parts["cars"], [1, 2, 3, 4, 7, 8, 11]),
                      ObjectClass.PEDESTRIAN: (parts["pedestrians"], [1, 2]),
                      ObjectClass.OBSTACLE: (parts["obstacles"], [1, 2, 5, 6])}
            cols = {ObjectClass.CAR: ["x", "y", "cos_yaw", "sin_yaw", "size_x", "size_y", "team"],
                    ObjectClass.PEDESTRIAN: ["x", "y"], ObjectClass.OBSTACLE: ["x", "y", "size_x", "size_y"]}
            for row in det[1:]:
                cls = ObjectClass(int(row[F["class_id"]]))
                if cls == ObjectClass.LANE:
                    continue
                table, columns = tables[cls]
                table = table[table[:, 0] > 0]
                want = row[[F[c] for c in cols[cls]]]
                gap = np.abs(table[:, columns] - want).max(axis=1)
                assert gap.min() < 2e-4, (agent, cls, want, table[:, columns])
                matched[cls] += 1
            assert np.all(det[:, F["confidence"]] == 1.0)                      # perception='none': certain
    assert all(count > 20 for count in matched.values()), matched


def test_partial_features_are_clipped_and_bad_perception_refused():
    env = parallel_env(n_cars=2, observation="partial", perception={"preset": "realistic", "noise_magnitude": 5})
    obs, _ = env.reset(seed=0)
    assert np.abs(obs["car_0"]["detections"][0]).max() <= feature_bound(env.config)
    with pytest.raises(ValueError, match="unknown driving perception preset"):
        parallel_env(observation="partial", perception="blurry")
    with pytest.raises(ValueError, match="perception must be"):
        parallel_env(observation="partial", perception=3)


def test_play_watch_writes_a_gif_with_one_cars_detections(tmp_path):
    import json
    import subprocess
    import sys
    from PIL import Image
    gif = tmp_path / "car1.gif"
    base = [sys.executable, "-m", "dynenv_ros.envs.play", "--scenario", "driving", "--cars", "3", "--seconds", "0.5",
            "--pixels-per-metre", "1.5", "--json"]
    watched = subprocess.run(base + ["--watch", "1", "--gif", str(gif)], capture_output=True, text=True, timeout=120)
    assert watched.returncode == 0, watched.stderr
    plain = subprocess.run(base + ["--gif", str(tmp_path / "plain.gif")], capture_output=True, text=True, timeout=120)
    assert json.loads(watched.stdout) == json.loads(plain.stdout)       # perception draws from its own generator
    assert json.loads(watched.stdout)["frames"] == 6
    with Image.open(gif) as image, Image.open(tmp_path / "plain.gif") as other:
        assert image.format == "GIF" and image.n_frames == 6
        image.seek(3)
        other.seek(3)
        drawn = np.asarray(image.convert("RGB"), np.int16)
        assert drawn.shape == np.asarray(other.convert("RGB")).shape
        assert np.abs(drawn - np.asarray(other.convert("RGB"), np.int16)).sum(axis=2).astype(bool).sum() > 50
    bad = subprocess.run(base + ["--watch", "3"], capture_output=True, text=True, timeout=120)
    assert bad.returncode == 2 and "--watch must be a car id in 0..2" in bad.stderr
