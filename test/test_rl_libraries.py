"""RL users' standard tools batch the padded observation: PettingZoo → SuperSuit → Stable-Baselines3 PPO.

``observation="padded"`` exists so that off-the-shelf libraries take the env as it is. These tests run the real
env through SuperSuit's vector env (``pettingzoo_env_to_vec_env_v1`` + ``concat_vec_envs_v1``, the route the
PettingZoo docs give for SB3) and train SB3's PPO on it with the Dict of Boxes observation as it is
(``MultiInputPolicy``, no flattening) and the ``MultiDiscrete`` action of ``head_mode='discrete'``.

SuperSuit's SB3 wrapper forwards ``seed()`` to a gymnasium vector env that has none, so ``PPO(seed=...)`` and the
wrapper's ``reset(seed=...)`` raise AttributeError (SuperSuit 3.11.0): seed the batch through ``vec_env.venv.reset``
(sub-env i gets seed + i) and torch / numpy through ``stable_baselines3.common.utils.set_random_seed``. SuperSuit's
SB3 wrapper folds truncations into ``dones``, and the envs carry no legacy ``TimeLimit.truncated`` info, so SB3
would take the time-limit end of an episode for a terminal state (no bootstrapping from ``terminal_observation``):
``envs.sb3_time_limit.sb3_time_limit_v0`` adds SB3's key before SuperSuit.
"""
from __future__ import annotations

import numpy as np
import pytest
import supersuit as ss
import torch
from stable_baselines3 import PPO
from stable_baselines3.common.utils import set_random_seed
from stable_baselines3.common.vec_env import VecMonitor

from dynenv_ros.envs.robocup_v0 import parallel_env
from dynenv_ros.envs.sb3_time_limit import sb3_time_limit_v0

PLAYERS_PER_TEAM = 2
AGENTS = 2 * PLAYERS_PER_TEAM
COPIES = 2                                      # SuperSuit's num_vec_envs: worlds in the batch
EPISODE_SECONDS = 15.0                          # 30 motion periods: many truncations and automatic resets
ENV_SETTINGS = dict(players_per_team=PLAYERS_PER_TEAM, observation="padded", episode_seconds=EPISODE_SECONDS)


def make_env():
    return parallel_env(**ENV_SETTINGS)


def make_vec_env(env):
    """The standard route: one vector slot per agent, COPIES worlds side by side, SB3's VecEnv interface."""
    vec_env = ss.pettingzoo_env_to_vec_env_v1(sb3_time_limit_v0(env))
    return ss.concat_vec_envs_v1(vec_env, num_vec_envs=COPIES, num_cpus=0, base_class="stable_baselines3")


@pytest.fixture
def one_thread():
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


def test_supersuit_batch_is_the_envs_own_observations():
    env = make_env()
    vec_env = make_vec_env(env)
    space = env.observation_space(env.possible_agents[0])
    assert vec_env.num_envs == COPIES * AGENTS
    assert all(env.observation_space(agent) == space for agent in env.possible_agents)
    assert vec_env.observation_space == space
    assert vec_env.action_space == env.action_space(env.possible_agents[0])

    seed = 11
    batched, _ = vec_env.venv.reset(seed=seed)              # sub-env c is reset with seed + c
    references = [make_env() for _ in range(COPIES)]
    expected = [ref.reset(seed=seed + c)[0] for c, ref in enumerate(references)]
    action_space = env.action_space(env.possible_agents[0])
    action_space.seed(0)
    for step in range(3):
        assert set(batched) == set(space.spaces)
        for key, box in space.spaces.items():
            assert batched[key].shape == (COPIES * AGENTS, *box.shape) and batched[key].dtype == np.float32
            for c in range(COPIES):
                for i, agent in enumerate(env.possible_agents):
                    np.testing.assert_array_equal(batched[key][c * AGENTS + i], expected[c][agent][key],
                                                  err_msg=f"step {step}, world {c}, {agent}, {key}")
        assert batched["landmark_mask"].any() and batched["object_mask"].any()   # real detections, not only padding
        # The same actions, as SB3 hands them to the batch (one row per agent slot) and as dicts to the envs.
        actions = np.stack([action_space.sample() for _ in range(COPIES * AGENTS)])
        batched, rewards, terminations, truncations, _ = vec_env.venv.step(actions)
        expected_rewards = []
        for c, ref in enumerate(references):
            obs, ref_rewards, *_ = ref.step({agent: actions[c * AGENTS + i]
                                             for i, agent in enumerate(ref.possible_agents)})
            expected[c] = obs
            expected_rewards += [ref_rewards[agent] for agent in ref.possible_agents]
        np.testing.assert_allclose(rewards, expected_rewards, rtol=1e-6)
        assert not terminations.any() and not truncations.any()


def test_sb3_sees_the_time_limit_as_a_truncation_with_its_final_observation():
    """What SB3's rollout collection reads to bootstrap: ``TimeLimit.truncated`` and ``terminal_observation``."""
    vec_env = make_vec_env(make_env())
    vec_env.venv.reset(seed=3)
    action_space = vec_env.action_space
    action_space.seed(3)
    periods = make_env().config.episode_periods
    for period in range(1, periods + 1):
        _, _, dones, infos = vec_env.step(np.stack([action_space.sample() for _ in range(vec_env.num_envs)]))
        assert dones.all() == (period == periods) and dones.any() == dones.all()
        assert all(info["TimeLimit.truncated"] is (period == periods) for info in infos)
    assert all(info["terminal_observation"] is not None for info in infos)


# SB3 asks the batch for render_mode through get_attr, which SuperSuit's gymnasium vector env lacks; it falls back
# to None, which is this env's render_mode anyway.
@pytest.mark.filterwarnings("ignore:The `render_mode` attribute is not defined:UserWarning")
def test_stable_baselines3_ppo_learns_from_the_supersuit_batch(one_thread):
    set_random_seed(0)
    env = make_env()
    vec_env = VecMonitor(make_vec_env(env))                 # episode returns and lengths, as users log them
    model = PPO("MultiInputPolicy", vec_env, n_steps=128, batch_size=256, n_epochs=2, device="cpu",
                policy_kwargs=dict(net_arch=dict(pi=[32], vf=[32])))
    assert model.observation_space == env.observation_space(env.possible_agents[0])
    before = [p.detach().clone() for p in model.policy.parameters()]

    total = 8192                                            # agent transitions: 1,024 steps of each of 2 worlds
    model.learn(total_timesteps=total)

    assert model.num_timesteps >= total
    changed = [not torch.equal(b, p.detach()) for b, p in zip(before, model.policy.parameters())]
    assert any(changed), "PPO's update left every parameter as it was"
    assert all(torch.isfinite(p).all() for p in model.policy.parameters())
    # Episodes ran to their truncation through SuperSuit's automatic resets: full-length episodes were logged.
    periods = env.config.episode_periods
    assert len(model.ep_info_buffer) >= COPIES * AGENTS
    assert all(info["l"] == periods for info in model.ep_info_buffer)
