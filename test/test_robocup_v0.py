"""The PettingZoo Parallel environment, its determinism, bad input, and the vectorised batch."""
import math

import numpy as np
import pytest
from pettingzoo.test import parallel_api_test, parallel_seed_test

from dynenv_ros.envs.robocup_v0 import parallel_env
from dynenv_ros.envs.vector import SoccerVectorEnv


@pytest.mark.parametrize("settings,cycles", [
    ({"players_per_team": 2}, 300),
    ({"players_per_team": 1, "head_mode": "continuous", "observation": "full"}, 300),
    ({"players_per_team": 5, "perception": "dynenv"}, 100),
    ({"players_per_team": 1, "observation": "image", "image_size": (32, 24)}, 30)])
def test_passes_pettingzoo_parallel_api_test(settings, cycles):
    with pytest.warns(UserWarning, match="unknown option"):    # the API test passes a dummy reset option
        parallel_api_test(parallel_env(**settings), num_cycles=cycles)


def test_passes_pettingzoo_seed_test():
    parallel_seed_test(lambda: parallel_env(players_per_team=2, falls={"p_walk": 0.05, "p_kick": 0.2}))


def _flat(observation):
    """One float vector of a whole observation (detections of every frame, proprioception), for comparisons."""
    if isinstance(observation, dict):
        return np.concatenate([_flat(observation[k]) for k in sorted(observation)])
    if isinstance(observation, tuple):
        return np.concatenate([np.append(len(o), _flat(o)) for o in observation])
    return np.asarray(observation, np.float64).ravel()


def _rollout(seed, periods=None, **settings):
    env = parallel_env(**settings)
    obs, _ = env.reset(seed=seed)
    for agent in env.possible_agents:
        env.action_space(agent).seed(seed)
    trace = [np.concatenate([_flat(obs[a]) for a in env.possible_agents])]
    rewards = []
    while env.agents and (periods is None or len(rewards) < periods):
        actions = {a: env.action_space(a).sample() for a in env.agents}
        obs, rew, term, trunc, info = env.step(actions)
        trace.append(np.concatenate([_flat(obs[a]) for a in env.possible_agents]))
        rewards.append([rew[a] for a in env.possible_agents])
    return trace, np.array(rewards), env


def test_same_seed_and_actions_give_the_same_episode_and_another_seed_does_not():
    settings = {"players_per_team": 2, "falls": {"p_walk": 0.02, "p_kick": 0.2}}
    a, ra, env = _rollout(7, **settings)
    b, rb, _ = _rollout(7, **settings)
    c, rc, _ = _rollout(8, **settings)
    assert len(ra) == env.config.episode_periods == 240
    assert len(a) == len(b) and all(np.array_equal(x, y) for x, y in zip(a, b))
    np.testing.assert_array_equal(ra, rb)
    assert not all(np.array_equal(x, y) for x, y in zip(a[:50], c[:50]))


def test_every_agent_is_truncated_at_the_time_limit_and_stepping_on_is_refused():
    env = parallel_env(episode_seconds=1.5)
    env.reset(seed=1)
    for expected in (False, False, True):
        _, _, term, trunc, info = env.step({a: env.action_space(a).sample() for a in env.agents})
        assert set(trunc.values()) == {expected} and set(term.values()) == {False}
        assert set(info["team_a_0"]["reward_terms"]) == {"primary", "rule", "auxiliary", "observation"}
    assert env.agents == []
    with pytest.raises(RuntimeError, match="reset"):
        env.step({})


def test_observations_and_state_lie_in_their_spaces_and_use_team_frames():
    env = parallel_env(players_per_team=2, observation="full")
    obs, _ = env.reset(seed=3)
    for agent, o in obs.items():
        assert env.observation_space(agent).contains(o)
    assert env.state_space.contains(env.state())
    # Kickoff positions: every robot is in its own half, which its team frame shows as x < 0, facing +x.
    for o in obs.values():
        assert o[0] < 0 and o[2] == pytest.approx(1.0)


def test_reset_option_chooses_the_kickoff_team():
    env = parallel_env(players_per_team=1, observation="full")
    env.reset(seed=0, options={"kickoff_team": "b"})
    assert env.world.state.ball_owner == -1
    obs, _ = env.reset(seed=0, options={"kickoff_team": "a"})
    assert env.world.state.ball_owner == 1 and obs["team_a_0"][13] == 1.0 and obs["team_b_0"][13] == -1.0
    with pytest.raises(ValueError, match="kickoff_team"):
        env.reset(options={"kickoff_team": "c"})


@pytest.mark.parametrize("bad,message", [
    (np.array([0, 0, 0]), r"team_a_1: action must have shape \(4,\)"),
    (np.array([5, 0, 0, 3]), r"team_a_1: action field 'walk'=5 is out of range"),
    (np.array([0, 3, 0, 3]), r"team_a_1: action field 'turn'=3"),
    (np.array([0, 0, -1, 3]), r"team_a_1: action field 'kick'=-1"),
    (np.array([0, 0, 0, 7]), r"team_a_1: action field 'head'=7 is out of range"),
    (np.array([0.5, 0, 0, 3]), r"team_a_1: action field 'walk' must be an integer"),
    (np.array([0, 0, 0, np.nan]), r"team_a_1: action field 'head' must be an integer"),
    ("walk", r"team_a_1: action must"),
])
def test_bad_actions_name_the_robot_and_field_and_do_not_advance_the_world(bad, message):
    env = parallel_env(players_per_team=2)
    env.reset(seed=0)
    actions = {a: np.array([1, 0, 0, 3]) for a in env.agents}
    actions["team_a_1"] = bad
    before = env.state()
    with pytest.raises(ValueError, match=message):
        env.step(actions)
    assert env.world.tick == 0
    np.testing.assert_array_equal(env.state(), before)


def test_continuous_head_refuses_nan_and_out_of_range():
    env = parallel_env(players_per_team=1, head_mode="continuous")
    env.reset(seed=0)
    good = {"motion": np.array([0, 0, 0]), "head": np.array([0.1], np.float32)}
    for head, message in ((np.nan, "must be finite"), (1.0, "beyond")):
        with pytest.raises(ValueError, match=f"team_b_0: action field 'head'.*{message}"):
            env.step({"team_a_0": good, "team_b_0": {"motion": np.array([0, 0, 0]), "head": np.array([head])}})
    with pytest.raises(ValueError, match="team_b_0: action mapping needs exactly the keys"):
        env.step({"team_a_0": good, "team_b_0": {"motion": [0, 0, 0]}})
    env.step({"team_a_0": good, "team_b_0": good})
    assert env.world.robots[0].head_yaw == pytest.approx(0.1)


def test_unknown_or_missing_agents_are_refused():
    env = parallel_env(players_per_team=1)
    env.reset(seed=0)
    action = np.array([0, 0, 0, 3])
    with pytest.raises(ValueError, match="unknown agent 'team_c_0'"):
        env.step({"team_a_0": action, "team_b_0": action, "team_c_0": action})
    with pytest.raises(ValueError, match="no action for team_b_0"):
        env.step({"team_a_0": action})
    with pytest.raises(ValueError, match="unknown agent"):
        env.observation_space("nobody")


@pytest.mark.parametrize("settings,message", [
    ({"players_per_team": 0}, "players_per_team"), ({"players_per_team": 6}, "players_per_team"),
    ({"speed": 3}, "unknown soccer setting"), ({"motion": {"forward_step": math.nan}}, "finite"),
    ({"rates": {"vision_period_ticks": 7}}, "whole number of vision periods"),
    ({"falls": {"p_kick": 1.5}}, "probability"), ({"head_mode": "analog"}, "head_mode"),
    ({"render_mode": "human"}, "render_mode")])
def test_bad_settings_are_refused_with_the_setting_named(settings, message):
    with pytest.raises(ValueError, match=message):
        parallel_env(**settings)


def test_render_gives_an_rgb_array():
    env = parallel_env(players_per_team=1, render_mode="rgb_array")
    env.reset(seed=0)
    frame = env.render()
    assert frame.ndim == 3 and frame.shape[2] == 3 and frame.dtype == np.uint8


def _vector_rollout(backend, periods=30):
    rng = np.random.default_rng(5)
    with SoccerVectorEnv(3, backend=backend, config={"players_per_team": 1, "episode_seconds": 10.0,
                                                        "falls": {"p_walk": 0.05}}, observation="full") as env:
        obs = [env.reset(seed=11)]
        rewards, finals = [], []
        for _ in range(periods):
            actions = rng.integers([0, 0, 0, 0], [5, 3, 3, 7], size=(3, 2, 4))
            result = env.step(actions)
            obs.append(result.observations)
            rewards.append(result.reward_terms)
            finals.append((result.truncated.copy(), sorted(result.final_observations)))
    return np.stack(obs), np.stack(rewards), finals


def test_vector_backends_agree_and_reset_finished_episodes():
    """Ground-truth batches (the padded ones with perception: test_vector_env.py)."""
    a_obs, a_rew, a_finals = _vector_rollout("inprocess")
    b_obs, b_rew, b_finals = _vector_rollout("subprocess")
    np.testing.assert_array_equal(a_obs, b_obs)
    np.testing.assert_array_equal(a_rew, b_rew)
    # 10 s episodes = 20 periods: every env finishes at period 20, returns its final observation and restarts.
    for step, (truncated, finished) in enumerate(a_finals):
        assert list(truncated) == [step == 19] * 3 and finished == ([0, 1, 2] if step == 19 else [])
    assert not np.array_equal(a_obs[0], a_obs[1])   # environments differ from each other and over time
    assert not np.array_equal(a_obs[0][0], a_obs[0][1])


def test_vector_env_refuses_bad_shapes_and_backends():
    with SoccerVectorEnv(2, config={"players_per_team": 1}, observation="full") as env:
        env.reset(seed=0)
        with pytest.raises(ValueError, match=r"shape \(2, 2, 4\)"):
            env.step(np.zeros((3, 2, 4), int))
        with pytest.raises(ValueError, match="env 1 robot 0: action field 'walk'=9"):
            env.step(np.array([[[0, 0, 0, 3]] * 2, [[9, 0, 0, 3], [0, 0, 0, 3]]]))
    with pytest.raises(ValueError, match="backend"):
        SoccerVectorEnv(2, backend="threads")
