"""The auxiliary losses the update adds to PPO's (A2C's) terms: the self-supervised heads (localization,
reconstruction), curiosity for a continuous action vector (``agent.losses.icm_losses`` is the one-hot actions'), and
imitation of a teacher (not in the paper; ``TrainConfig.teacher``). Pretraining uses the self-supervised ones alone.
"""
from __future__ import annotations

from typing import Any, Mapping, cast

import torch
from torch import Tensor

from dynenv_ros.agent.losses import localization_loss, masked_mean, rcm_forward_loss, reconstruction_loss
from dynenv_ros.learning.algo.policy import head_outputs, log_prob_entropy
from dynenv_ros.scenarios import scenario_of

BALL_ANCHOR = ((0.0, 0.0),)


def self_supervised_losses(out: Any, targets: Mapping[str, Tensor], use_localization: bool,
                           use_reconstruction: bool) -> dict[str, Tensor]:
    """Localization (pose) and reconstruction (ball, robots) losses over every observation of the rollout."""
    losses: dict[str, Tensor] = {}
    if use_localization:
        losses["localization"] = localization_loss(out.pose, targets["pose"])
    if use_reconstruction:
        ball = reconstruction_loss(out.ball.unsqueeze(-2), out.ball_confidence.unsqueeze(-1),
                                   targets["ball"].unsqueeze(-2), targets["ball_known"].unsqueeze(-1) > 0.5,
                                   anchors=BALL_ANCHOR)
        robots = reconstruction_loss(out.robots, out.robot_confidence, targets["robots"],
                                     targets["robots_known"] > 0.5, binary_fields=(4, 5))
        losses["reconstruction"] = cast(Tensor, sum(ball.values()) + sum(robots.values()))
        losses["recon_ball_position"] = ball["position"].detach()
        losses["recon_robot_position"] = robots["position"].detach()
    return losses


def continuous_icm_losses(phi: Tensor, actions: Tensor, heads: Any, mask: Tensor, use_rcm: bool
                          ) -> dict[str, Tensor]:
    """``icm_losses`` for a continuous action vector (driving's 3 normalised values): the same (RCM-weighted)
    forward loss on [φ_t, a_t] with φ_{t+1} detached, and an inverse model that regresses a_t from (φ_t, φ_{t+1})
    — the masked mean over transitions of the mean squared error over the action's dimensions."""
    phi_t, phi_next = phi[:-1], phi[1:]
    target = phi_next.detach()
    pred = heads.forward_model(phi_t, actions)
    if use_rcm:
        forward = rcm_forward_loss(pred, target, heads.rcm_attention(target), mask)
    else:
        forward = masked_mean(((pred - target) ** 2).mean(-1), mask)
    (guess,) = heads.inverse_model(phi_t, phi_next)
    inverse = masked_mean(((guess - actions) ** 2).mean(-1), mask)
    return {"forward": forward, "inverse": inverse}


def imitation_loss(agent: Any, out: Any, teacher: Tensor, acting: Tensor) -> tuple[Tensor, dict[str, Tensor]]:
    """−log π(teacher's action | s) summed over the heads, averaged over the steps where the robot could act; and
    agreement over those steps. Categorical heads (soccer's walk, turn, kick, head; driving's acceleration,
    steering): the fraction where the policy's most likely action equals the teacher's on every head
    (``teacher_agreement``) and on each head (``teacher_agreement_<head>``). Driving's continuous head: the mean
    absolute difference between the policy's mean command and the teacher's (normalised units,
    ``teacher_command_error``) — there is no most likely value to agree on."""
    log_prob, _ = log_prob_entropy(agent, out, teacher)
    heads = scenario_of(agent).categorical_heads(getattr(agent, "action_mode", None) or "discrete")
    with torch.no_grad():
        if not heads:
            T, B = teacher.shape[:2]
            means = torch.stack([d.mean for d in agent.distributions(head_outputs(out, flat=True))], -1)
            error = (means.reshape(T, B, -1) - teacher).abs().mean(-1)
            agreement = {"teacher_command_error": masked_mean(error, acting)}
        else:
            same = torch.stack([getattr(out, h).argmax(-1) for h in heads], -1) == teacher
            agreement = {"teacher_agreement": masked_mean(same.all(-1).float(), acting)}
            agreement.update({f"teacher_agreement_{h}": masked_mean(same[..., i].float(), acting)
                              for i, h in enumerate(heads)})
    return -masked_mean(log_prob, acting), agreement
