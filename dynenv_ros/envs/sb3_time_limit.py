"""Stable-Baselines3's time-limit key for the SuperSuit route, added outside the envs.

The envs say "ended by the time limit" the Gymnasium/PettingZoo way, in ``truncations``; they carry no legacy
``TimeLimit.truncated`` info. SB3 bootstraps a truncated episode from ``terminal_observation`` only when the info
says ``TimeLimit.truncated`` — its own VecEnvs add that key from Gymnasium's ``truncated`` flag, but SuperSuit's
SB3 wrapper (``concat_vec_envs_v1(..., base_class="stable_baselines3")``) folds truncations into ``dones`` and
drops them. Wrap the Parallel env with ``sb3_time_limit_v0`` before SuperSuit, and SB3 bootstraps the time limit
instead of taking it for a terminal state::

    env = ss.pettingzoo_env_to_vec_env_v1(sb3_time_limit_v0(parallel_env(observation="padded")))
"""
from __future__ import annotations

from typing import Any

from pettingzoo import ParallelEnv
from pettingzoo.utils.wrappers import BaseParallelWrapper

TIME_LIMIT_KEY = "TimeLimit.truncated"


class SB3TimeLimitWrapper(BaseParallelWrapper):
    """Copies each agent's truncation (and not termination) into ``infos[agent]["TimeLimit.truncated"]``."""

    def step(self, actions: dict[str, Any]):
        observations, rewards, terminations, truncations, infos = self.env.step(actions)
        infos = {agent: {**info, TIME_LIMIT_KEY: bool(truncations.get(agent, False))
                         and not terminations.get(agent, False)} for agent, info in infos.items()}
        return observations, rewards, terminations, truncations, infos


def sb3_time_limit_v0(env: ParallelEnv) -> SB3TimeLimitWrapper:
    """The Parallel env with SB3's time-limit key in its step infos (SuperSuit-style versioned name)."""
    return SB3TimeLimitWrapper(env)
