"""The AEC form of a Parallel env, PettingZoo's standard way, for both worlds (``robocup_v0.env``/``raw_env``,
``driving_v0.env``/``raw_env``).

``raw_aec``: PettingZoo's ``parallel_to_aec_wrapper`` — agents act in turn and the world steps once the last live
agent has acted, so it plays exactly the Parallel env's episode. ``wrapped_aec``: that under
``OrderEnforcingWrapper``, as ``pettingzoo.utils.conversions.parallel_to_aec`` applies it and PettingZoo's docs use
AEC envs. No out-of-bounds wrapper: the worlds already refuse a bad action with ValueError naming the agent and
field, and clipping would accept what the Parallel env refuses. ``aec_to_parallel(env(...))`` hands back the
Parallel env.
"""
from __future__ import annotations

from pettingzoo import AECEnv, ParallelEnv
from pettingzoo.utils.conversions import parallel_to_aec_wrapper
from pettingzoo.utils.wrappers import OrderEnforcingWrapper


def raw_aec(parallel: ParallelEnv) -> AECEnv:
    return parallel_to_aec_wrapper(parallel)


def wrapped_aec(parallel: ParallelEnv) -> AECEnv:
    return OrderEnforcingWrapper(raw_aec(parallel))


__all__ = ["raw_aec", "wrapped_aec"]
