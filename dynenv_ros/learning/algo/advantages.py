"""Returns and advantages of a rollout: GAE(λ) with episode ends respected and time-limit truncation bootstrapped.

A2C's n-step returns are the special case λ = 1 (the sum of discounted rewards up to the rollout's end, bootstrapped
with the critic there), so both algorithms share this one function. DynEnv ignored episode ends (its done mask was
hard-coded to zeros, docs/original.md §9.4/§12.15), so its returns ran across resets; here an episode end cuts the sum,
and a truncated (time-limit) end is bootstrapped from the critic's value of the episode's *final* observation, since the
game did not really end there for the agent's purposes — it ran out of clock.
"""
from __future__ import annotations

import torch
from torch import Tensor


def generalized_advantages(rewards: Tensor, values: Tensor, episode_end: Tensor, truncated: Tensor,
                           final_values: Tensor, gamma: float, lam: float) -> tuple[Tensor, Tensor]:
    """(advantages (T, B), returns (T, B)).

    rewards (T, B): reward of step t. values (T+1, B): V(s_t), with values[T] the critic at the observation after
    the last step. episode_end (T, B): an episode ended with step t (the next observation starts a new one).
    truncated (T, B): that end was the time limit; final_values (T, B) is then V(final observation of the episode)
    and is used in place of values[t+1]; a terminated end bootstraps with 0.
    δ_t = r_t + γ·next_t − V(s_t);  A_t = δ_t + γλ·(1 − end_t)·A_{t+1};  returns = A + V(s_t).
    """
    steps = rewards.shape[0]
    if values.shape[0] != steps + 1:
        raise ValueError(f"values must have T+1 = {steps + 1} steps, got {values.shape[0]}")
    end = episode_end.to(rewards.dtype)
    cut = truncated.to(rewards.dtype) * end
    next_values = values[1:] * (1.0 - end) + final_values * cut
    deltas = rewards + gamma * next_values - values[:-1]
    advantages = torch.zeros_like(rewards)
    running = torch.zeros_like(rewards[0])
    for t in range(steps - 1, -1, -1):
        running = deltas[t] + gamma * lam * (1.0 - end[t]) * running
        advantages[t] = running
    return advantages, advantages + values[:-1]
