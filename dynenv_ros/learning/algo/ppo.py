"""PPO and A2C updates of the DynEnv agent, with the paper's auxiliary losses.

One function, ``update``, serves both algorithms (A2C is the one-epoch, one-minibatch, unclipped special case):

1. Advantages from the behaviour values stored at acting time (``advantages.generalized_advantages``; A2C uses
   λ = 1, the paper's n-step returns over the rollout, bootstrapped with the critic).
2. For each epoch, the robots are split into minibatches of *whole sequences*; each minibatch is re-run from the
   recurrent state stored at the rollout's start (``Rollout.initial_state``), with the state zeroed where an episode
   starts, by ``DynEnvAgent.forward_sequence`` over the T+1 observations (the last one gives φ_T for curiosity).
3. Loss = policy + value_coef·value − entropy_coef·entropy + forward_coef·forward + inverse_coef·inverse +
   ltp_coef·LTP + self_supervised_coef·(localization + reconstruction), each term switchable by the variant,
   + imitation_coef·imitation when the rollout has teacher labels (not in the paper; see ``TrainConfig.teacher``).

Policy loss: PPO's clipped surrogate min(r·A, clip(r, 1±ε)·A) with r = π(a|s)/π_old(a|s) on the stored behaviour
log-probabilities (DynEnv's PPO had the sign flipped and compared freshly resampled actions, §12.13); A2C's
−log π(a|s)·A. Both are averaged over the steps where the robot could act (not fallen or penalized: its action had
no effect there, so those samples only add variance). Entropy is per agent (the sum over the action heads of each
robot's own policy entropy), not DynEnv's "batch entropy" of the mean policy (§9.4).

Driving (``networks.agent.scenario == 'driving'``): the same update over cars, with driving's heads (two categorical
or three clipped Gaussians, ``driving.agent_actions``) and inputs (its layout spec); the rollout's ``alive`` mask
(T+1, B) removes every step after a car's own episode end from every term — value included; the curiosity models
take the one-hot [3, 3] actions (discrete) or the continuous action vector, whose inverse model regresses it
(squared error) instead of classifying. No localization or reconstruction (the config refuses them).
"""
from __future__ import annotations

import logging
import time
from dataclasses import dataclass
from typing import Any, Callable, Mapping

import numpy as np
import torch
from torch import Tensor

from dynenv_ros.agent.losses import icm_losses, ltp_loss, masked_mean
from dynenv_ros.learning.algo.advantages import generalized_advantages
from dynenv_ros.learning.algo.auxiliary import continuous_icm_losses, imitation_loss, self_supervised_losses
from dynenv_ros.learning.algo.networks import TrainingNetworks, action_features
from dynenv_ros.learning.algo.policy import head_outputs, log_prob_entropy, run_sequence
from dynenv_ros.learning.config import TrainConfig

LOG = logging.getLogger(__name__)


@dataclass
class UpdateSettings:
    """The numbers of one update (from ``TrainConfig``; see its field documentation)."""
    algorithm: str = "a2c"
    gamma: float = 0.99
    gae_lambda: float = 1.0
    epochs: int = 1
    minibatches: int = 1
    clip: float = 0.2
    clip_value_loss: bool = False
    normalize_advantages: bool = False
    target_kl: float | None = None
    policy_coef: float = 1.0          # 0 with value and entropy 0: the auxiliary losses alone (pretraining)
    value_coef: float = 0.5
    entropy_coef: float = 0.1
    max_grad_norm: float = 0.5
    forward_coef: float = 1e-2
    inverse_coef: float = 1e-2
    ltp_coef: float = 1e-3
    self_supervised_coef: float = 1e-2
    use_forward: bool = True
    use_rcm: bool = True
    use_inverse: bool = True
    use_ltp: bool = True
    use_localization: bool = False
    use_reconstruction: bool = False
    intrinsic_reward_coef: float = 0.0
    imitation_coef: float = 0.0       # weight of −log π(teacher's action | s); the trainer sets it per update
    # PPO on lagging experience (the asynchronous runner): clip around the policy as it is when the update starts
    # (the proximal policy) instead of the behaviour policy, weight each sample by the truncated ratio proximal /
    # behaviour, and take advantages from the current critic (``_proximal``).
    proximal: bool = False

    @property
    def ppo(self) -> bool:
        return self.algorithm == "ppo"


def update_settings(cfg: TrainConfig) -> UpdateSettings:
    """The variant's loss switches and the config's numbers, in the form ``update`` takes. ``use_forward`` is on
    for ICM's plain forward model *and* RCM's attention-weighted one (``use_rcm`` picks the weighting): ``update``
    adds the forward loss only under ``use_forward``."""
    losses = cfg.losses()
    ppo = cfg.algorithm == "ppo"
    return UpdateSettings(
        algorithm=cfg.algorithm, gamma=cfg.gamma, gae_lambda=cfg.gae_lambda,
        epochs=cfg.ppo_epochs if ppo else 1, minibatches=cfg.ppo_minibatches if ppo else 1, clip=cfg.ppo_clip,
        clip_value_loss=cfg.clip_value_loss, normalize_advantages=cfg.normalize_advantages,
        target_kl=cfg.target_kl, value_coef=cfg.value_coef, entropy_coef=cfg.entropy_coef,
        max_grad_norm=cfg.max_grad_norm, forward_coef=cfg.forward_coef, inverse_coef=cfg.inverse_coef,
        ltp_coef=cfg.ltp_coef, self_supervised_coef=cfg.self_supervised_coef,
        use_forward=losses.forward, use_rcm=losses.rcm_attention, use_inverse=losses.inverse, use_ltp=losses.ltp,
        use_localization=losses.localization, use_reconstruction=losses.reconstruction,
        intrinsic_reward_coef=cfg.intrinsic_reward_coef, imitation_coef=cfg.imitation_weight(0),
        proximal=ppo and cfg.runner == "async")


@dataclass
class ActorCriticLoss:
    """PPO's (A2C's) loss of a minibatch and its parts, scalar tensors: ``total`` = policy_coef·policy +
    value_coef·value − entropy_coef·entropy; ``approx_kl`` and ``clip_fraction`` carry no gradient."""
    total: Tensor
    policy: Tensor
    value: Tensor
    entropy: Tensor
    approx_kl: Tensor
    clip_fraction: Tensor


def ppo_loss(log_prob: Tensor, old_log_prob: Tensor, advantages: Tensor, entropy: Tensor, value: Tensor,
             returns: Tensor, acting: Tensor, alive: Tensor, s: UpdateSettings, old_value: Tensor | None = None
             ) -> ActorCriticLoss:
    """The policy, value and entropy terms over (T, B) steps, as CleanRL's ``ppo.py`` writes them.

    - policy: PPO's clipped surrogate −mean min(r·A, clip(r, 1 − ε, 1 + ε)·A), r = exp(log π − log π_old) against
      the behaviour's ``old_log_prob`` (``s.algorithm`` 'ppo', ε = ``s.clip``); A2C's −mean log π·A otherwise;
    - value: mean (V − returns)², or with ``s.clip_value_loss`` the larger of that and (V_clipped − returns)², V_clipped
      = ``old_value`` + clip(V − ``old_value``, −ε, ε);
    - entropy: the mean of the per-robot policy entropy (a bonus: subtracted).

    Policy, entropy, KL and clip fraction average over the steps where the robot could ``act`` (its action had an
    effect), the value over the steps it was ``alive`` (bool masks, (T, B)). ``advantages`` as the update uses them
    (normalised, weighted)."""
    log_ratio = log_prob - old_log_prob
    ratio = log_ratio.exp()
    if s.ppo:
        surrogate = torch.minimum(ratio * advantages, ratio.clamp(1 - s.clip, 1 + s.clip) * advantages)
        policy_loss = -masked_mean(surrogate, acting)
    else:
        policy_loss = -masked_mean(log_prob * advantages, acting)
    value_error = (value - returns) ** 2
    if s.clip_value_loss:
        if old_value is None:
            raise ValueError("clip_value_loss needs the behaviour values (old_value)")
        clipped = old_value + (value - old_value).clamp(-s.clip, s.clip)
        value_error = torch.maximum(value_error, (clipped - returns) ** 2)
    value_loss = masked_mean(value_error, alive)
    entropy_mean = masked_mean(entropy, acting)
    total = s.policy_coef * policy_loss + s.value_coef * value_loss - s.entropy_coef * entropy_mean
    with torch.no_grad():
        approx_kl = masked_mean((ratio - 1) - log_ratio, acting)
        clip_fraction = masked_mean(((ratio - 1).abs() > s.clip).float(), acting)
    return ActorCriticLoss(total, policy_loss, value_loss, entropy_mean, approx_kl, clip_fraction)


def minibatch_loss(networks: TrainingNetworks, rollout: Mapping[str, Any], rows: Tensor, advantages: Tensor | None,
                   returns: Tensor | None, s: UpdateSettings, log: Callable[[str, Tensor | float], None],
                   intrinsic_returns: Tensor | None = None, intrinsic_advantages: Tensor | None = None
                   ) -> tuple[Tensor, float]:
    """(loss, approximate KL) of one minibatch of robot sequences (``rows``): the sequences re-run from their start
    state, PPO's (A2C's) terms (``ppo_loss``), then the auxiliary ones the settings switch on (curiosity, the
    self-supervised heads, imitation: ``auxiliary``); ``log(name, value)`` takes every term. ``advantages`` None:
    decoupled PPO fused into this pass (``_fused_proximal``)."""
    agent = networks.agent
    T = rollout["actions"].shape[0]
    every_row = len(rows) == rollout["actions"].shape[1] and bool((rows == torch.arange(len(rows), device=rows.device)).all())
    obs = rollout["obs"] if every_row else {k: v[:, rows] for k, v in rollout["obs"].items()}   # A2C: no copy
    out = run_sequence(agent, obs, _initial_state(networks, rollout, rows), rollout["starts"][:, rows])
    actions = rollout["actions"][:, rows]
    acting = rollout["can_act"][:T, rows]
    everywhere = rollout["alive"][:T, rows] if "alive" in rollout else torch.ones_like(acting)
    if "teacher_driven" in rollout:       # rows that executed the teacher's actions: off-policy, no RL terms there
        on_policy = ~rollout["teacher_driven"][rows].unsqueeze(0).expand_as(acting)
        imitated, acting, everywhere = acting, acting & on_policy, on_policy
    else:
        imitated = acting
    step_out = head_outputs(out, steps=T)
    log_prob, entropy = log_prob_entropy(agent, step_out, actions)
    weights: Tensor | None
    if advantages is None:
        adv, target, old_log_prob, weights = _fused_proximal(rollout, rows, log_prob, out.value.detach(), s,
                                                             intrinsic_advantages, log)
    else:
        assert returns is not None                  # given with the advantages
        adv, target, old_log_prob = advantages[:, rows], returns[:, rows], rollout["log_probs"][:, rows]
        weights = rollout["sample_weights"][:, rows] if "sample_weights" in rollout else None
    if s.normalize_advantages:
        valid = adv[acting] if acting.any() else adv.reshape(-1)
        adv = (adv - valid.mean()) / (valid.std(unbiased=False) + 1e-8)
    if weights is not None:               # decoupled PPO: the behaviour policy's correction
        adv = adv * weights
    old_value = rollout["values"][:T, rows] if s.clip_value_loss else None
    terms = ppo_loss(log_prob, old_log_prob, adv, entropy, out.value[:T], target, acting, everywhere, s, old_value)
    loss = terms.total
    if intrinsic_returns is not None:
        intrinsic_value = networks.intrinsic_critic(out.phi[:T].detach()).squeeze(-1)
        intrinsic_value_loss = ((intrinsic_value - intrinsic_returns[:, rows]) ** 2).mean()
        loss = loss + s.value_coef * intrinsic_value_loss
        log("intrinsic_value_loss", intrinsic_value_loss.detach())
    log("policy_loss", terms.policy.detach())
    log("value_loss", terms.value.detach())
    log("entropy", terms.entropy.detach())
    log("approx_kl", terms.approx_kl)
    log("clip_fraction", terms.clip_fraction)

    curious = s.use_forward or s.use_inverse or s.use_ltp
    if curious:
        transition = imitated & ~rollout["episode_end"][:, rows]     # every executed action, whoever chose it
        onehot = action_features(actions, networks.action_heads, networks.continuous_actions)
        heads = networks.curiosity
        phi = out.phi
        if networks.continuous_actions:
            icm = continuous_icm_losses(phi, onehot, heads, transition, s.use_rcm)
        else:
            icm = icm_losses(phi, onehot, actions, heads.forward_model, heads.inverse_model, transition,
                             attention=heads.rcm_attention if s.use_rcm else None)
        if s.use_forward:
            loss = loss + s.forward_coef * icm["forward"]
            log("forward_loss", icm["forward"].detach())
        if s.use_inverse:
            loss = loss + s.inverse_coef * icm["inverse"]
            log("inverse_loss", icm["inverse"].detach())
        if s.use_ltp:
            ltp = ltp_loss(phi, onehot, heads.ltp, heads.ltp_attention, transition)
            loss = loss + s.ltp_coef * ltp.loss
            log("ltp_loss", ltp.loss.detach())
    if s.use_localization or s.use_reconstruction:
        targets = {k: v[:, rows] for k, v in rollout["targets"].items()}
        supervised = self_supervised_losses(out, targets, s.use_localization, s.use_reconstruction)
        for name in ("localization", "reconstruction"):
            if name in supervised:
                loss = loss + s.self_supervised_coef * supervised[name]
        for name, value in supervised.items():
            log(f"{name}_loss" if not name.startswith("recon_") else name, value.detach())
        if s.use_localization:
            with torch.no_grad():
                error = (out.pose[..., :2] - targets["pose"][..., :2]).norm(dim=-1)
            for metres in (0.25, 0.5, 1.0):
                log(f"localization_within_{int(metres * 100)}cm", (error < metres).float().mean())
    if s.imitation_coef > 0.0 and "teacher_actions" in rollout:
        imitation, agreement = imitation_loss(agent, step_out, rollout["teacher_actions"][:, rows], imitated)
        loss = loss + s.imitation_coef * imitation
        log("imitation_loss", imitation.detach())
        for name, value in agreement.items():
            log(name, value)
    log("loss", loss.detach())
    return loss, float(terms.approx_kl)


def _initial_state(networks: TrainingNetworks, rollout: Mapping[str, Any], rows: Tensor) -> tuple[Tensor, ...]:
    if "seed_pose" in rollout:       # privileged seeding: rebuilt with gradient, so the seeder learns
        return networks.seeded_state(rollout["seed_pose"][rows])
    return tuple(x[rows] for x in rollout["initial_state"])


def _fused_proximal(rollout: Mapping[str, Any], rows: Tensor, log_prob: Tensor, values: Tensor, s: UpdateSettings,
                    intrinsic_advantages: Tensor | None, log: Callable[[str, Tensor | float], None]
                    ) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """Decoupled PPO's proximal quantities of one minibatch from its own forward pass (one epoch: the weights have
    not stepped on these rows yet): (advantages and returns from the current critic, the proximal
    log-probabilities, the truncated weights min(1, π_prox / π_behaviour)) — what ``_proximal`` gets from a pass of
    its own. A minibatch holds whole robot sequences, so its returns need nothing from other rows."""
    with torch.no_grad():
        advantages, returns = generalized_advantages(
            rollout["rewards"][:, rows], values, rollout["episode_end"][:, rows], rollout["truncated"][:, rows],
            rollout["final_values"][:, rows], s.gamma, s.gae_lambda)
        if intrinsic_advantages is not None:
            advantages = advantages + intrinsic_advantages[:, rows]
        proximal = log_prob.detach()
        log_ratio = proximal - rollout["log_probs"][:, rows]
        weights = log_ratio.clamp(max=0.0).exp()
        log("proximal_weight", weights.mean())
        log("proximal_kl", ((log_ratio.exp() - 1) - log_ratio).mean())
        log("explained_variance", 1.0 - torch.var(returns - values[:-1]) / torch.var(returns).clamp(min=1e-8))
    return advantages, returns, proximal, weights


NONFINITE_SKIPS = ("nonfinite_loss_skipped", "nonfinite_gradient_skipped")


def _skip_step(optimizer: torch.optim.Optimizer, what: str, value: float) -> None:
    """A minibatch whose loss or gradient norm is NaN or infinite (poisoned experience, a diverging run): no
    optimizer step, its gradients dropped — the weights never see it. Logged at ERROR; ``update`` counts it."""
    optimizer.zero_grad(set_to_none=True)
    LOG.error("non-finite %s (%r): the update step is skipped, the weights are unchanged", what, value)


def update(networks: TrainingNetworks, optimizer: torch.optim.Optimizer, rollout: Mapping[str, Any], settings: UpdateSettings,
           generator: torch.Generator | None = None) -> dict[str, float]:
    """One PPO or A2C update on a rollout (``Rollout.as_tensors()``); returns the logged scalars."""
    s = settings
    T, B = rollout["actions"].shape[:2]
    stats: dict[str, list[float]] = {}
    epochs = s.epochs if s.ppo else 1
    # decoupled PPO (``_proximal``); with one epoch each minibatch's own forward pass, made before any step on its
    # rows, is the proximal one, so it costs no extra pass (``_fused_proximal``)
    fused = s.proximal and s.ppo and epochs == 1
    if s.proximal and s.ppo and not fused:
        rollout = _proximal(networks, rollout, stats)
    advantages = returns = None
    if not fused:
        advantages, returns = generalized_advantages(
            rollout["rewards"], rollout["values"], rollout["episode_end"], rollout["truncated"],
            rollout["final_values"], s.gamma, s.gae_lambda)
    minibatches = max(1, min(s.minibatches, B))
    intrinsic_returns = intrinsic_advantages = None
    if s.intrinsic_reward_coef > 0:
        intrinsic_advantages, intrinsic_returns, intrinsic = _intrinsic(networks, rollout, s)
        if advantages is not None:
            advantages = advantages + intrinsic_advantages
        stats["intrinsic_reward"] = [float(intrinsic.mean())]

    def log(name: str, value: Tensor | float) -> None:
        stats.setdefault(name, []).append(float(value))

    timing = {"forward_backward": 0.0, "optimizer": 0.0}
    stop = False
    for epoch in range(epochs):  # noqa: B007 - read after the loop (epochs_run)
        # row indices on the CPU (the CPU generator draws them); they index tensors on any device
        order = torch.randperm(B, generator=generator, device="cpu") if minibatches > 1 else torch.arange(B, device="cpu")
        for chunk in order.chunk(minibatches):
            started = time.perf_counter()
            loss, kl = minibatch_loss(networks, rollout, chunk, advantages, returns, s, log, intrinsic_returns,
                                       intrinsic_advantages)
            optimizer.zero_grad(set_to_none=True)
            if not bool(torch.isfinite(loss.detach())):
                _skip_step(optimizer, "loss", float(loss.detach()))
                stats.setdefault("nonfinite_loss_skipped", []).append(1.0)
                continue
            loss.backward()
            backward_done = time.perf_counter()
            norm = torch.nn.utils.clip_grad_norm_(networks.parameters(), s.max_grad_norm, foreach=True)
            if not bool(torch.isfinite(norm)):
                _skip_step(optimizer, "gradient norm", float(norm))
                stats.setdefault("nonfinite_gradient_skipped", []).append(1.0)
                continue
            optimizer.step()
            timing["forward_backward"] += backward_done - started
            timing["optimizer"] += time.perf_counter() - backward_done
            log("grad_norm", norm)
            if s.ppo and s.target_kl is not None and kl > s.target_kl:
                stop = True
                break
        if stop:
            break
    skips = {name: float(len(stats.pop(name, []))) for name in NONFINITE_SKIPS}
    out = {name: float(np.mean(values)) for name, values in stats.items() if values}
    out.update(skips)                   # counts (0 when none), not means: the runners and the trainer add them up
    out["epochs_run"] = float(epoch + 1)
    out["seconds_forward_backward"] = timing["forward_backward"]
    out["seconds_optimizer"] = timing["optimizer"]
    if returns is not None:           # (fused proximal: logged per minibatch)
        explained = 1.0 - torch.var(returns - rollout["values"][:-1]) / torch.var(returns).clamp(min=1e-8)
        out["explained_variance"] = float(explained)
    return out


@torch.no_grad()
def _proximal(networks: TrainingNetworks, rollout: Mapping[str, Any], stats: dict[str, list[float]]) -> dict[str, Any]:
    """Decoupled PPO for experience that lags (Hilton et al. 2022, "Batch size-invariance for policy
    optimization"): one forward pass with the weights as they are now gives the proximal log-probabilities (the
    clip's centre from here on), the current critic's values (fresher advantages than the behaviour's), and the
    per-sample weight min(1, π_prox / π_behaviour) that corrects for the behaviour policy (truncated like
    V-trace's ρ̄ = 1). The bootstrap values of truncated episodes stay the behaviour's (their observations are not
    in the rollout)."""
    T, B = rollout["actions"].shape[:2]
    rows = torch.arange(B, device="cpu")
    out = run_sequence(networks.agent, rollout["obs"], _initial_state(networks, rollout, rows), rollout["starts"])
    log_prob, _ = log_prob_entropy(networks.agent, head_outputs(out, steps=T), rollout["actions"])
    log_ratio = log_prob - rollout["log_probs"]
    weights = log_ratio.clamp(max=0.0).exp()
    stats["proximal_weight"] = [float(weights.mean())]
    stats["proximal_kl"] = [float(((log_ratio.exp() - 1) - log_ratio).mean())]
    return {**rollout, "log_probs": log_prob, "values": out.value.reshape(T + 1, B), "sample_weights": weights}


@torch.no_grad()
def _intrinsic(networks: TrainingNetworks, rollout: Mapping[str, Any], s: UpdateSettings) -> tuple[Tensor, Tensor, Tensor]:
    """Curiosity as a reward (off in the paper, docs/original.md §6.3): the forward model's error on each transition
    (attention-weighted under RCM), scaled by ``intrinsic_reward_coef``, with its own critic and advantage —
    added to the extrinsic advantage. An episode's last transition has no successor and earns nothing."""
    T, B = rollout["actions"].shape[:2]
    rows = torch.arange(B, device="cpu")
    out = run_sequence(networks.agent, rollout["obs"], _initial_state(networks, rollout, rows), rollout["starts"])
    phi = out.phi
    heads = networks.curiosity
    taken = action_features(rollout["actions"], networks.action_heads, networks.continuous_actions)
    error = (heads.forward_model(phi[:-1], taken) - phi[1:]) ** 2
    if s.use_rcm:
        error = error * heads.rcm_attention(phi[1:])
    ended = rollout["episode_end"]
    reward = s.intrinsic_reward_coef * error.mean(-1) * (~ended).to(error.dtype)
    values = networks.intrinsic_critic(phi).squeeze(-1)
    advantages, returns = generalized_advantages(reward, values, ended, torch.zeros_like(ended),
                                                 torch.zeros_like(reward), s.gamma, s.gae_lambda)
    return advantages, returns, reward
