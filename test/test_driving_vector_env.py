"""DrivingVectorEnv: driving worlds with perception batched into the padded layout; both backends bit-identical, the
same arrays as driving_v0(observation="padded") with the same seed, per-car termination, actions checked first."""
import numpy as np
import pytest

from dynenv_ros.envs.driving_v0 import parallel_env
from dynenv_ros.envs.vector import DrivingVectorEnv, _seeds
from soccer_helpers import assert_identical

# 3 s episodes = 30 periods: a 45-step rollout crosses an automatic reset.
SHORT = {"n_cars": 3, "episode_seconds": 3.0, "pedestrians": {"count_min": 3, "count_max": 5},
         "obstacles": {"count_min": 2, "count_max": 4}}


def _actions(rng, mode, envs, cars, w):
    if mode == "discrete":
        return rng.integers(0, 3, (envs, cars, 2))
    return np.stack([rng.uniform(-1, 1, (envs, cars)), rng.uniform(0, 1, (envs, cars)),
                     rng.uniform(-w, w, (envs, cars))], axis=-1).astype(np.float32)


def _rollout(backend, steps, mode="discrete", envs=3, seed=7, **kwargs):
    rng = np.random.default_rng(0)
    config = {**SHORT, "action_mode": mode}
    with DrivingVectorEnv(envs, backend=backend, workers=2, config=config, **kwargs) as env:
        out = [env.reset(seed=seed)]
        w = env.config.cars.max_yaw_rate
        for _ in range(steps):
            r = env.step(_actions(rng, mode, envs, 3, w))
            out.append((r.observations, r.rewards, r.reward_terms, r.terminated, r.truncated, r.agents_terminated,
                        r.final_observations, r.dropped_detections))
    return out


@pytest.mark.parametrize("mode", ["discrete", "continuous"])
def test_backends_give_bit_identical_driving_batches_across_episode_ends(mode):
    a = _rollout("inprocess", 45, mode)
    b = _rollout("subprocess", 45, mode)        # 2 shards: worlds 0-1 in this process, world 2 in a worker
    assert_identical(a, b)
    assert sum(bool((step[3] | step[4]).any()) for step in a[1:]) >= 1
    layout = DrivingVectorEnv(1, backend="inprocess", config=SHORT).layout
    assert {k: v.shape for k, v in a[0].items()} == {k: (3, 3) + s for k, s in layout.shapes().items()}


def test_each_world_is_driving_v0_padded_with_its_seed():
    a = _rollout("inprocess", 25)
    env = parallel_env(observation="padded", **SHORT)
    obs, _ = env.reset(seed=_seeds(7, 3)[1])
    rng = np.random.default_rng(0)
    cars = env.possible_agents
    for t in range(26):
        batch = a[t] if t == 0 else a[t][0]
        for i, car in enumerate(cars):
            if car in obs:
                for key, value in obs[car].items():
                    np.testing.assert_array_equal(value, batch[key][1, i], err_msg=f"{t} {key}")
        if t == 25 or not env.agents:
            break
        actions = _actions(rng, "discrete", 3, 3, 0.0)[1]
        obs, rewards, terminations, _, _ = env.step({c: actions[i] for i, c in enumerate(cars) if c in env.agents})
        for i, car in enumerate(cars):
            if car in rewards:
                assert rewards[car] == a[t + 1][1][1, i]
                assert terminations[car] == a[t + 1][5][1, i]


def test_full_observation_and_refusals():
    with DrivingVectorEnv(2, backend="inprocess", config=SHORT, observation="full") as env:
        obs = env.reset(seed=1)
        ref = parallel_env(observation="full", **SHORT)
        first, _ = ref.reset(seed=_seeds(1, 2)[0])
        np.testing.assert_array_equal(obs[0], np.stack([first[c] for c in ref.possible_agents]))
        with pytest.raises(ValueError, match="shape"):
            env.step(np.zeros((2, 3, 3), int))
        with pytest.raises(ValueError, match="env 1 car 2"):
            env.step(np.array([[[0, 0]] * 3, [[0, 0], [0, 0], [0, 3]]]))
    with pytest.raises(ValueError, match="perception"):
        DrivingVectorEnv(1, config=SHORT, observation="full", perception="none")
    with pytest.raises(ValueError, match="max_objects"):
        DrivingVectorEnv(1, config=SHORT, max_objects=0)
