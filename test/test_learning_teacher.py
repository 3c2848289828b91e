"""Imitation of a scripted teacher (DAgger): the worlds label every robot with the scripted team's action for the
state its observation shows, the collector stores the labels beside the learner's own actions, the imitation loss
reaches the actor (never the critic) and, on its own, makes the policy agree with the teacher."""
import math

import numpy as np
import pytest
import torch

from dynenv_ros.agent.network import DynEnvAgent
from dynenv_ros.envs.teacher import action_indices
from dynenv_ros.envs.vector import SoccerVectorEnv, _seeds
from dynenv_ros.learning.algo.ppo import UpdateSettings, minibatch_loss
from dynenv_ros.learning.config import ConfigError, TrainConfig
from dynenv_ros.learning.algo.networks import TrainingNetworks
from dynenv_ros.learning.sampling.collector import RolloutCollector
from dynenv_ros.soccer.actions import Kick, SoccerAction, Turn, Walk, parse_action
from dynenv_ros.soccer.config import SoccerConfig
from dynenv_ros.soccer.scripted import act_all, team_policies
from dynenv_ros.soccer.world import SoccerWorld
from imitation_helpers import follow_labels, imitate, imitation_measures, imitation_update_loss, touched_by_imitation

HEAD_STEP = math.radians(12.5)     # MotionConfig: one discrete head unit
HEAD_UNITS = 3                     # indices 0..6, 3 = no turn


def test_action_indices_round_the_head_turn_to_the_nearest_step():
    row = action_indices(SoccerAction(Walk.FORWARD, Turn.RIGHT, Kick.LEFT_FOOT, 2.2 * HEAD_STEP), HEAD_STEP, HEAD_UNITS)
    assert row == (1, 2, 1, 3 + 2)
    assert action_indices(SoccerAction(head_yaw_delta=-0.4 * HEAD_STEP), HEAD_STEP, HEAD_UNITS)[3] == 3
    assert action_indices(SoccerAction(head_yaw_delta=-10 * HEAD_STEP), HEAD_STEP, HEAD_UNITS)[3] == 0
    assert action_indices(SoccerAction(head_yaw_delta=10 * HEAD_STEP), HEAD_STEP, HEAD_UNITS)[3] == 6


def test_following_the_labels_replays_the_scripted_team_and_backends_agree():
    """Every robot plays its teacher label: the worlds then move exactly as worlds stepped directly by the chaser
    team (its head turns rounded the same way), and the two backends give the same labels."""
    config = SoccerConfig.from_mapping({"players_per_team": 1, "episode_seconds": 30.0})
    worlds, periods, seed = 2, 40, 5
    labels, terms = follow_labels(
        lambda backend: SoccerVectorEnv(worlds, backend=backend, config=config, perception="none", teacher="chaser"),
        periods, seed)
    assert labels.dtype == np.int64 and labels.shape == (periods + 1, worlds, 2, 4)
    assert (labels[..., 0] == Walk.FORWARD).any() and (labels[..., 3] != HEAD_UNITS).any()   # it moves and looks

    policies = team_policies(1, "chaser", field=config.field, motion=config.motion)
    for e, world_seed in enumerate(_seeds(seed, worlds)):
        world = SoccerWorld(config)
        world.reset(seed=world_seed)
        for t in range(periods):
            expected = [action_indices(a, HEAD_STEP, HEAD_UNITS) for a in act_all(policies, world.snapshot())]
            np.testing.assert_array_equal(labels[t, e], expected)
            result = world.step([parse_action(f"robot {i}", np.array(row), head_mode="discrete",
                                              head_step=HEAD_STEP, head_units=HEAD_UNITS)
                                 for i, row in enumerate(expected)])
            np.testing.assert_array_equal(terms[t, e, :3], np.asarray(result.rewards)[:3])


def test_teacher_refusals():
    with pytest.raises(ValueError, match="teacher"):
        SoccerVectorEnv(1, backend="inprocess", teacher="random")
    with pytest.raises(ValueError, match="discrete"):
        SoccerVectorEnv(1, backend="inprocess", config={"head_mode": "continuous"}, teacher="chaser")
    with SoccerVectorEnv(1, backend="inprocess") as env:
        env.reset(seed=0)
        with pytest.raises(RuntimeError, match="without a teacher"):
            _ = env.teacher_actions
        assert env.step(np.zeros((1, 4, 4), np.int64) + [0, 0, 0, 3]).teacher_actions is None
    with pytest.raises(ConfigError, match="imitation_coef.*teacher"):
        TrainConfig(imitation_coef=1.0)
    with pytest.raises(ConfigError, match="teacher"):
        TrainConfig(teacher="keeper_and_chasers", imitation_coef=1.0)
    with pytest.raises(ConfigError, match="imitation_decay_env_steps"):
        TrainConfig(teacher="chaser", imitation_coef=1.0, imitation_decay_env_steps=-1)


def test_imitation_weight_falls_linearly_to_its_final_value():
    cfg = TrainConfig(teacher="chaser", imitation_coef=1.0, imitation_final_coef=0.2, imitation_decay_env_steps=1000)
    assert cfg.imitation_weight(0) == 1.0
    assert cfg.imitation_weight(500) == pytest.approx(0.6)
    assert cfg.imitation_weight(1000) == pytest.approx(0.2)
    assert cfg.imitation_weight(10**6) == pytest.approx(0.2)
    assert TrainConfig(teacher="chaser", imitation_coef=0.5).imitation_weight(10**6) == 0.5


def _teacher_setup(seed, episode_seconds):
    """Two 1v1 worlds labelled by the chaser, a fresh agent learning both robots of each world."""
    torch.manual_seed(seed)
    env = SoccerVectorEnv(2, backend="inprocess", config={"players_per_team": 1, "episode_seconds": episode_seconds},
                          teacher="chaser")
    agent = DynEnvAgent()
    collector = RolloutCollector(env, agent, np.arange(2), None, torch.Generator().manual_seed(seed), seed=seed)
    return env, TrainingNetworks(agent, horizon=3), collector


@pytest.fixture(scope="module")
def teacher_rollout():
    env, networks, collector = _teacher_setup(1, 3.0)
    first_labels = env.teacher_actions
    rollout = collector.collect(8)
    yield networks, rollout, first_labels
    env.close()


def test_the_collector_stores_the_labels_of_each_acting_observation(teacher_rollout):
    _, rollout, first_labels = teacher_rollout
    assert rollout.teacher_actions.shape == (8, 4, 4)
    np.testing.assert_array_equal(rollout.teacher_actions[0], first_labels.reshape(4, 4))
    assert "teacher_actions" in rollout.as_tensors()


def test_imitation_loss_reaches_the_actor_and_encoder_not_the_critic(teacher_rollout):
    networks, rollout, _ = teacher_rollout
    tensors = rollout.as_tensors()
    touched = touched_by_imitation(networks, tensors)
    assert any(n.startswith("agent.walk") for n in touched), sorted(touched)[:5]
    assert any(n.startswith("agent.objects") for n in touched)
    assert not any(n.startswith("agent.critic") for n in touched)
    networks.zero_grad(set_to_none=True)
    assert float(imitation_update_loss(networks, tensors, coef=0.0).detach()) == 0.0   # every other term is off too


def test_imitation_alone_makes_the_policy_agree_with_the_teacher(teacher_rollout):
    networks, rollout, _ = teacher_rollout
    tensors = rollout.as_tensors()

    def agreement():
        loss, agree = imitation_measures(networks, tensors)
        assert agree["teacher_agreement"] <= min(agree[f"teacher_agreement_{h}"] for h in ("walk", "turn", "kick", "head"))
        return loss, agree["teacher_agreement"]

    loss0, agree0 = agreement()
    imitate(networks, tensors, 60)
    loss1, agree1 = agreement()
    assert agree0 < 0.5 and loss0 > 2.0          # an untrained policy: ~ log(5·3·3·7) ≈ 5.75 nats
    assert agree1 > 0.9 and loss1 < 0.5 * loss0


def test_teacher_driven_worlds_execute_the_labels_and_give_the_rl_terms_nothing():
    env, networks, collector = _teacher_setup(2, 2.0)
    with pytest.raises(ValueError, match="worlds must be in 0..2"):
        collector.drive_with_teacher(3)
    collector.drive_with_teacher(1)                 # world 0's two robots follow the teacher, world 1 is the learner's
    rollout = collector.collect(10)                 # 2 s episodes = 4 periods: episodes end inside the rollout
    env.close()
    np.testing.assert_array_equal(rollout.teacher_driven, [True, True, False, False])
    np.testing.assert_array_equal(rollout.actions[:, :2], rollout.teacher_actions[:, :2])
    assert not (rollout.actions[:, 2:] == rollout.teacher_actions[:, 2:]).all()
    assert np.isfinite(rollout.log_probs).all()
    assert collector.finished and len(collector.finished) % 2 == 0
    assert len(collector.finished) == 2 * int(rollout.episode_end[:, 2].sum())   # world 1's robots only

    tensors = rollout.as_tensors()
    tensors["teacher_driven"] = torch.ones(4, dtype=torch.bool)       # every row off-policy
    T, B = rollout.steps, rollout.robots
    ones = torch.ones(T, B)
    rl_only = UpdateSettings(policy_coef=1.0, value_coef=1.0, entropy_coef=0.1, use_forward=False, use_rcm=False,
                             use_inverse=False, use_ltp=False, imitation_coef=0.0)
    loss, _ = minibatch_loss(networks, tensors, torch.arange(B), ones, ones * 5.0, rl_only, lambda *a: None)
    assert float(loss.detach()) == 0.0
    tensors["teacher_driven"] = torch.tensor([True, True, False, False])
    loss, _ = minibatch_loss(networks, tensors, torch.arange(B), ones, ones * 5.0, rl_only, lambda *a: None)
    assert float(loss.detach()) != 0.0


def test_teacher_driven_config_refusals():
    with pytest.raises(ConfigError, match="teacher_driven_worlds.*teacher"):
        TrainConfig(teacher_driven_worlds=2)
    with pytest.raises(ConfigError, match="teacher_driven_worlds"):
        TrainConfig(teacher="chaser", imitation_coef=1.0, num_envs=4, teacher_driven_worlds=4)
    with pytest.raises(ConfigError, match="teacher_driven_env_steps"):
        TrainConfig(teacher="chaser", teacher_driven_worlds=1, teacher_driven_env_steps=-5)
    TrainConfig(teacher="chaser", imitation_coef=1.0, num_envs=4, teacher_driven_worlds=3)
