"""Imitation of the scripted driver (driving's teacher): every car labelled with the driver's action for the state its
observation shows, in the agent's action units; labels stored by the collector; the imitation loss reaches the actor
and, on its own, makes the policy agree with the driver; config refusals."""
import math

import numpy as np
import pytest
import torch

from dynenv_ros.agent.network import DynEnvAgent
from dynenv_ros.driving.config import DrivingConfig
from dynenv_ros.driving.scripted import ScriptedDriver
from dynenv_ros.driving.world import DrivingWorld
from dynenv_ros.envs.vector import DrivingVectorEnv, _seeds
from dynenv_ros.learning.config import ConfigError, TrainConfig, load_config
from dynenv_ros.learning.algo.networks import TrainingNetworks
from dynenv_ros.learning.sampling.collector import RolloutCollector
from imitation_helpers import follow_labels, imitate, imitation_measures, touched_by_imitation

# docs/driving.md: the steering limit is 2° per 100 ms (0.349 rad/s); a continuous label's steering is the command / it
MAX_YAW_RATE = math.radians(2.0) / 0.1


@pytest.mark.parametrize("mode", ["discrete", "continuous"])
def test_following_the_labels_replays_the_scripted_driver_and_backends_agree(mode):
    """Every car drives by its label: the worlds then move exactly as worlds driven directly by the scripted driver,
    and the two backends give the same labels."""
    config = {"n_cars": 3, "action_mode": mode}
    worlds, periods, seed = 2, 40, 4
    unit = np.array([1.0, 1.0, MAX_YAW_RATE]) if mode == "continuous" else 1
    labels, terms = follow_labels(
        lambda backend: DrivingVectorEnv(worlds, backend=backend, config=config, perception="none", teacher="scripted"),
        periods, seed, lambda labels: labels * unit)
    width, dtype = (2, np.int64) if mode == "discrete" else (3, np.float32)
    assert labels.shape == (periods + 1, worlds, 3, width) and labels.dtype == dtype

    driving = DrivingConfig.from_mapping(config)
    driver = ScriptedDriver(driving)
    for e, world_seed in enumerate(_seeds(seed, worlds)):
        world = DrivingWorld(driving)
        world.reset(seed=world_seed)
        for t in range(periods):
            expected = np.asarray(driver.actions(world))
            if mode == "continuous":
                np.testing.assert_allclose(labels[t, e] * unit, expected, rtol=1e-6, atol=1e-6)
                assert (np.abs(labels[t, e]) <= 1.0 + 1e-6).all()             # within the normalised action box
            else:
                np.testing.assert_array_equal(labels[t, e], expected)
            result = world.step(expected)
            np.testing.assert_allclose(terms[t, e], np.asarray(result.rewards), rtol=0, atol=1e-5)
    if mode == "discrete":
        assert (labels[..., 0] == 2).any() and (labels[..., 1] != 1).any()     # it drives on and it steers


def test_driving_teacher_refusals():
    with pytest.raises(ValueError, match="teacher"):
        DrivingVectorEnv(1, backend="inprocess", teacher="chaser")
    with DrivingVectorEnv(1, backend="inprocess", perception="none") as env:
        env.reset(seed=0)
        with pytest.raises(RuntimeError, match="without a teacher"):
            _ = env.teacher_actions
    with pytest.raises(ConfigError) as error:
        load_config(None, ["scenario=driving", "teacher=chaser"])
    assert error.value.key == "teacher"
    with pytest.raises(ConfigError) as error:
        TrainConfig(teacher="scripted", imitation_coef=1.0)                     # soccer's teacher is the chaser
    assert error.value.key == "teacher"
    with pytest.raises(ConfigError) as error:
        load_config(None, ["scenario=driving", "teacher=scripted", "num_envs=4", "teacher_driven_worlds=1"])
    assert error.value.key == "teacher_driven_worlds"
    with pytest.raises(ConfigError) as error:
        load_config(None, ["scenario=driving", "imitation_coef=1"])
    assert error.value.key == "imitation_coef"
    cfg = load_config(None, ["scenario=driving", "teacher=scripted", "imitation_coef=1"])
    assert cfg.teacher == "scripted" and cfg.imitation_weight(0) == 1.0


def _setup(mode, seed=1):
    torch.manual_seed(seed)
    env = DrivingVectorEnv(2, backend="inprocess", perception="none", teacher="scripted",
                           config={"n_cars": 2, "action_mode": mode})
    agent = DynEnvAgent(16, scenario="driving", action_mode=mode)
    collector = RolloutCollector(env, agent, np.arange(2), None, torch.Generator().manual_seed(seed), seed=seed)
    return env, TrainingNetworks(agent, horizon=2), collector


@pytest.mark.parametrize("mode", ["discrete", "continuous"])
def test_the_labels_are_stored_and_imitation_alone_brings_the_policy_to_the_driver(mode):
    env, networks, collector = _setup(mode)
    first = env.teacher_actions
    try:
        rollout = collector.collect(12)
    finally:
        env.close()
    width = 2 if mode == "discrete" else 3
    assert rollout.teacher_actions.shape == (12, 4, width)
    np.testing.assert_array_equal(rollout.teacher_actions[0], first.reshape(4, width))
    tensors = rollout.as_tensors()
    touched = touched_by_imitation(networks, tensors)
    assert not any(n.startswith("agent.critic") for n in touched) and touched
    loss0, agree0 = imitation_measures(networks, tensors)
    imitate(networks, tensors, 80)
    loss1, agree1 = imitation_measures(networks, tensors)
    assert loss1 < loss0 - 0.5
    if mode == "discrete":          # an untrained policy picks the driver's row of 3 x 3 by chance: ~1/9 of the time
        assert agree0["teacher_agreement"] < 0.5 and agree1["teacher_agreement"] > 0.9
    else:                           # the mean command's distance to the driver's, in normalised units
        assert agree1["teacher_command_error"] < 0.5 * agree0["teacher_command_error"]
