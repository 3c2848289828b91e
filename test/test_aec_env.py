"""PettingZoo's AEC API for both worlds (``env`` / ``raw_env``), through PettingZoo's own conversion, and that it
plays exactly the Parallel env's episode; the infos carry no legacy ``TimeLimit.truncated`` key."""
from __future__ import annotations

import copy
from collections.abc import Callable
from typing import Any

import numpy as np
import pytest
from pettingzoo.test import api_test, parallel_api_test
from pettingzoo.utils.conversions import aec_to_parallel, parallel_to_aec_wrapper
from pettingzoo.utils.wrappers import OrderEnforcingWrapper

from dynenv_ros.envs import driving_v0, robocup_v0

SHORT_DRIVING = {"episode_seconds": 4.0, "pedestrians": {"count_min": 3, "count_max": 5},
                 "obstacles": {"count_min": 2, "count_max": 4}}
WORLDS = {
    "robocup": (robocup_v0, {"players_per_team": 2, "episode_seconds": 10.0}),
    "robocup_padded_continuous": (robocup_v0, {"players_per_team": 1, "episode_seconds": 5.0,
                                               "observation": "padded", "head_mode": "continuous"}),
    "driving": (driving_v0, {"n_cars": 3, **SHORT_DRIVING}),
    "driving_continuous": (driving_v0, {"n_cars": 2, "action_mode": "continuous", **SHORT_DRIVING}),
}


@pytest.mark.parametrize("world", WORLDS)
def test_aec_env_passes_pettingzoo_api_test(world):
    module, settings = WORLDS[world]
    with pytest.warns(UserWarning, match="unknown option"):     # the API test passes a dummy reset option
        api_test(module.env(**settings), num_cycles=100)


@pytest.mark.parametrize("world", ["robocup", "driving"])
def test_parallel_env_of_the_same_settings_passes_the_parallel_api_test(world):
    module, settings = WORLDS[world]
    with pytest.warns(UserWarning, match="unknown option"):
        parallel_api_test(module.parallel_env(**settings), num_cycles=100)


@pytest.mark.parametrize("module", [robocup_v0, driving_v0])
def test_env_is_the_standard_conversion_and_converts_back(module):
    raw = module.raw_env()
    assert type(raw) is parallel_to_aec_wrapper
    wrapped = module.env()
    assert isinstance(wrapped, OrderEnforcingWrapper) and type(wrapped.env) is parallel_to_aec_wrapper
    assert wrapped.metadata["name"] == module.parallel_env().metadata["name"]
    assert isinstance(aec_to_parallel(wrapped), type(module.parallel_env()))
    with pytest.raises(AssertionError, match="reset"):               # OrderEnforcingWrapper: reset first
        wrapped.step(None)


def _assert_same(a: Any, b: Any, where: str) -> None:
    """Equal observations, rewards and infos, nested dicts / tuples / arrays alike."""
    if isinstance(a, dict):
        assert isinstance(b, dict) and set(a) == set(b), where
        for key in a:
            _assert_same(a[key], b[key], f"{where}/{key}")
    elif isinstance(a, (tuple, list)):
        assert isinstance(b, (tuple, list)) and len(a) == len(b), where
        for i, (x, y) in enumerate(zip(a, b)):
            _assert_same(x, y, f"{where}[{i}]")
    else:
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b), err_msg=where)


def _planned_actions(make: Callable[..., Any], settings: dict[str, Any], periods: int) -> list[dict[str, Any]]:
    """The same seeded actions for both APIs: one per possible agent and period."""
    env = make(**settings)
    for i, agent in enumerate(env.possible_agents):
        env.action_space(agent).seed(100 + i)
    return [{a: env.action_space(a).sample() for a in env.possible_agents} for _ in range(periods)]


def _parallel_streams(module, settings, seed, plan):
    """Per agent, what it is told before each of its decisions: (observation, reward, terminated, truncated, info)."""
    env = module.parallel_env(**settings)
    obs, infos = env.reset(seed=seed)
    streams = {a: [(obs[a], 0, False, False, infos[a])] for a in env.agents}
    period = 0
    while env.agents:
        obs, rewards, terms, truncs, infos = env.step({a: plan[period][a] for a in env.agents})
        period += 1
        for a in obs:
            streams[a].append(copy.deepcopy((obs[a], rewards[a], terms[a], truncs[a], infos[a])))
    return streams, period


def _aec_streams(module, settings, seed, plan):
    env = module.env(**settings)
    env.reset(seed=seed)
    streams: dict[str, list] = {a: [] for a in env.agents}
    turns = dict.fromkeys(env.agents, 0)
    for agent in env.agent_iter():
        observation, reward, terminated, truncated, info = env.last()
        streams[agent].append(copy.deepcopy((observation, reward, terminated, truncated, info)))
        if terminated or truncated:
            env.step(None)
        else:
            env.step(plan[turns[agent]][agent])
            turns[agent] += 1
    return streams


@pytest.mark.parametrize("world", WORLDS)
def test_aec_and_parallel_play_the_same_episode_for_the_same_seed_and_actions(world):
    module, settings = WORLDS[world]
    plan = _planned_actions(module.parallel_env, settings, periods=200)
    parallel, periods = _parallel_streams(module, settings, seed=5, plan=plan)
    aec = _aec_streams(module, settings, seed=5, plan=plan)
    assert periods > 3
    assert set(aec) == set(parallel)
    for agent, stream in parallel.items():
        assert len(aec[agent]) == len(stream), agent
        for turn, (expected, got) in enumerate(zip(stream, aec[agent])):
            _assert_same(expected, got, f"{world} {agent} turn {turn}")
        assert stream[-1][2] or stream[-1][3], f"{agent}'s episode did not end"


@pytest.mark.parametrize("world", ["robocup", "driving"])
def test_infos_carry_no_legacy_time_limit_key(world):
    module, settings = WORLDS[world]
    env = module.parallel_env(**settings)
    _, infos = env.reset(seed=0)
    seen = [infos]
    truncated = False
    while env.agents:
        _, _, _, truncs, infos = env.step({a: env.action_space(a).sample() for a in env.agents})
        seen.append(infos)
        truncated = truncated or any(truncs.values())
    assert all("TimeLimit.truncated" not in info for step in seen for info in step.values())
    assert world != "robocup" or truncated                    # soccer always ends by its time limit
