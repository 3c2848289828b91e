"""Shared steps of the imitation tests (soccer's chaser, driving's scripted driver): the update with only the
imitation loss on, which parameters it reaches, a few optimiser steps of it, and the policy's agreement."""
from __future__ import annotations

import numpy as np
import torch

from dynenv_ros.learning.algo.auxiliary import imitation_loss
from dynenv_ros.learning.algo.ppo import UpdateSettings, minibatch_loss
from dynenv_ros.learning.algo.policy import head_outputs, run_sequence


def imitation_settings(**on) -> UpdateSettings:
    """Every loss off (policy, value, entropy, curiosity) but what ``on`` turns on."""
    base = dict(policy_coef=0.0, value_coef=0.0, entropy_coef=0.0, use_forward=False, use_rcm=False,
                use_inverse=False, use_ltp=False)
    base.update(on)
    return UpdateSettings(**base)


def imitation_update_loss(networks, tensors, coef: float = 1.0) -> torch.Tensor:
    """The update's minibatch loss over every row of a rollout with only the imitation term (weight ``coef``)."""
    T, B = tensors["actions"].shape[:2]
    zeros = torch.zeros(T, B)
    loss, _ = minibatch_loss(networks, tensors, torch.arange(B), zeros, zeros, imitation_settings(imitation_coef=coef),
                              lambda *a: None)
    return loss


def touched_by_imitation(networks, tensors) -> set[str]:
    """Names of the parameters the imitation loss gives a non-zero gradient."""
    networks.zero_grad(set_to_none=True)
    imitation_update_loss(networks, tensors).backward()
    return {n for n, p in networks.named_parameters() if p.grad is not None and p.grad.abs().sum() > 0}


def imitate(networks, tensors, updates: int, lr: float = 3e-3) -> None:
    """``updates`` Adam steps on the imitation loss alone."""
    optimizer = torch.optim.Adam(networks.parameters(), lr=lr)
    for _ in range(updates):
        loss = imitation_update_loss(networks, tensors)
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()


def imitation_measures(networks, tensors) -> tuple[float, dict[str, float]]:
    """The imitation loss of the policy now over every step of the rollout, and its agreement measures."""
    T, B = tensors["actions"].shape[:2]
    with torch.no_grad():
        out = run_sequence(networks.agent, tensors["obs"], tensors["initial_state"], tensors["starts"])
        acting = torch.ones(T, B, dtype=torch.bool)
        loss, agree = imitation_loss(networks.agent, head_outputs(out, steps=T), tensors["teacher_actions"], acting)
    return float(loss), {k: float(v) for k, v in agree.items()}


def follow_labels(make_env, periods: int, seed: int, to_actions=lambda labels: labels):
    """Step a vector env made by ``make_env(backend)`` with its own teacher labels for ``periods`` periods, in the
    in-process and the subprocess backend; both must give the same labels and rewards. Returns the labels
    (periods + 1, E, A, width) and reward terms (periods, E, T, A) of the in-process run."""
    runs = []
    for backend in ("inprocess", "subprocess"):
        with make_env(backend) as env:
            env.reset(seed=seed)
            labels, terms = [env.teacher_actions], []
            for _ in range(periods):
                step = env.step(to_actions(labels[-1]))
                labels.append(step.teacher_actions)
                terms.append(step.reward_terms)
            runs.append((np.stack(labels), np.stack(terms)))
    np.testing.assert_array_equal(runs[0][0], runs[1][0])
    np.testing.assert_array_equal(runs[0][1], runs[1][1])
    return runs[0]
