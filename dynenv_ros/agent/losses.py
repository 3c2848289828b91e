"""Losses of the DynEnv agent (Szemenyei & Reizinger, section 4) as plain torch modules and functions (no ROS):
curiosity (ICM, the Recurrent/Rational Curiosity Module RCM, Long-Term Prediction LTP), localization, and
reconstruction with field-fixed anchors.

Shapes: a rollout of T steps for N agents gives features φ of shape (T+1, N, D); actions are (T, N, A) one-hot
concatenations (A = Σ head sizes, see ``one_hot_actions``) or (T, N, H) per-head indices; masks are bool (T, N),
True = the agent may be trained at that step (not fallen, penalized or finished). Masked entries are selected out
with ``torch.where``, so they add nothing to a loss and get exactly zero gradient (their values must be finite).
Every loss is a scalar tensor that callers weight and add themselves; with no agent or no unmasked entry it is 0
(still attached to the graph, so backward works; only an LTP over a rollout of T = 0 steps is a constant 0).

How the paper's equations are read here (the paper leaves these open):
- Target detachment: by default the prediction targets φ_{t+1} (ICM/RCM) and φ_1..φ_H (LTP) are detached. The
  encoder is still trained by these losses through the predictors' inputs (φ_t, φ_0) and by the inverse loss
  through both φ_t and φ_{t+1}; what the detachment removes is the direct route by which the encoder could lower
  the forward error by moving the targets towards the predictions (a constant φ makes every forward loss 0).
  ``detach_target=False`` gives the original's behaviour (nothing detached).
- Eq. 1, J = (1/N) eᵀe with e = √W (φ − φ̂): N is read as the feature size D, i.e. J = mean_j W_j Δ_j² per sample,
  which is the plain ICM MSE when W = I; samples are then averaged over the unmasked (t, agent) pairs.
- "Attention" (eqs. 1, 2, 5) is softmax over the feature dimension of a linear map of its input (RCM: the target
  φ_{t+1}; LTP: W_i). Its weights sum to 1 over the D features, so a weighted term is about 1/D of an unweighted MSE;
  ``RCMAttention(unit_mean=True)`` multiplies by D (mean weight 1) for callers who want the scales comparable.
- Eq. 4: the sum runs over i = t+1 … t+N (N terms, the 1/N average); the paper's upper bound t+N+1 would need one
  feature vector beyond the rollout. Predictions start at t = 0 of the given φ (slice φ to start elsewhere), and
  N = min(horizon, T).
- Eqs. 5–6: w_1 = 1 ("the first prediction ... is not weighted", rather than the literal Attention(1), a learned
  constant); w_i = Attention(e_{i−1}) with e_{i−1} = (φ_{i−1} − φ̂_{i−1})², the *raw* previous squared error as eq. 6
  writes it (not the previous weighted error, which the prose "weighted based on the previous weights" might
  suggest). The original code also multiplied w by e_{i−1}; eq. 5 does not, so neither does this.
- Gradient through w: the paper detaches nothing, so the attention input e_{i−1} carries gradient into the
  predictors by default (``detach_weight_input=True`` stops it); the attention layer itself must get gradient, as
  J_LTP is the only loss that trains it.
- The Hadamard product of eq. 5 is reduced to a scalar by the mean over features (as eq. 1 with N = D), then by
  the mean over valid agents. Prediction i uses the transitions 0..i−1, so it is valid for an agent only if the
  mask is True at every one of those steps (cumulative mask).
"""
from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from typing import Any, NamedTuple

import numpy as np
import torch
import torch.nn.functional as F
from scipy.optimize import linear_sum_assignment
from torch import Tensor, nn

ROBOCUP_HEADS: tuple[int, ...] = (5, 3, 3, 7)   # step, turn, kick, head: the RoboCup MultiDiscrete action heads
# Field-fixed anchors of the 4 robot slots, in metres, team frame (x towards the opponent goal): one per quarter of
# the 9 x 6 m field, at its centre. DynEnv put them at (±0.5, ±0.5) normalised units; pass others to the functions.
ANCHORS: tuple[tuple[float, float], ...] = ((-2.25, -1.5), (-2.25, 1.5), (2.25, -1.5), (2.25, 1.5))


def masked_mean(values: Tensor, mask: Tensor | None) -> Tensor:
    """Mean of ``values`` where ``mask`` (a leading-dims prefix of ``values``' shape) is True; 0 when none is.

    Uses ``torch.where`` rather than multiplying by the mask, so masked entries never reach the result, and the
    result stays connected to the graph even when it is 0 (callers can always call backward).
    """
    if mask is None:
        mask = torch.ones(values.shape, dtype=torch.bool, device=values.device)
    mask = mask.to(torch.bool)
    while mask.dim() < values.dim():
        mask = mask.unsqueeze(-1)
    mask = mask.expand_as(values)
    return torch.where(mask, values, 0.0).sum() / mask.sum().clamp(min=1)


def _mean_or_zero(values: Tensor) -> Tensor:
    """Mean that is 0 (not NaN) for an empty tensor."""
    return values.sum() / max(values.numel(), 1)


def one_hot_actions(actions_index: Tensor, head_sizes: Sequence[int] = ROBOCUP_HEADS) -> Tensor:
    """(…, H) per-head indices → (…, Σ head_sizes) float concatenation of one-hot vectors (the models' action input).

    Negative indices (padding for agents that did not act) give an all-zero block instead of an error.
    """
    if actions_index.shape[-1] != len(head_sizes):
        raise ValueError(f"expected {len(head_sizes)} action heads, got shape {tuple(actions_index.shape)}")
    blocks = []
    for index, size in zip(actions_index.long().unbind(-1), head_sizes):
        valid = index >= 0
        blocks.append(F.one_hot(torch.where(valid, index, 0), size).float() * valid.unsqueeze(-1))
    return torch.cat(blocks, dim=-1)


# ---------------------------------------------------------------------------------------------------------------
# Curiosity: ICM and RCM

class ForwardModel(nn.Module):
    """f(φ_t, a_t) → φ̂_{t+1}: Linear(D+A → hidden) → LeakyReLU(0.1) → Linear(hidden → D) on [φ, a]."""

    def __init__(self, feature_size: int, action_size: int, hidden: int = 140) -> None:
        super().__init__()
        self.net = nn.Sequential(nn.Linear(feature_size + action_size, hidden), nn.LeakyReLU(0.1),
                                 nn.Linear(hidden, feature_size))

    def forward(self, phi: Tensor, action: Tensor) -> Tensor:
        predicted: Tensor = self.net(torch.cat([phi, action.to(phi.dtype)], dim=-1))
        return predicted


class InverseModel(nn.Module):
    """Logits of each action head from [φ_t, φ_{t+1}]: which action led from one state to the next.

    ``hidden=None`` is one linear layer per head on the 2D concatenation (as DynEnv); an int adds a shared
    Linear → LeakyReLU(0.1) trunk of that width (as in Pathak et al.'s ICM).
    """

    def __init__(self, feature_size: int, head_sizes: Sequence[int] = ROBOCUP_HEADS, hidden: int | None = None) -> None:
        super().__init__()
        self.head_sizes = tuple(head_sizes)
        width = 2 * feature_size
        self.trunk: nn.Module = nn.Identity()
        if hidden:
            self.trunk = nn.Sequential(nn.Linear(width, hidden), nn.LeakyReLU(0.1))
            width = hidden
        self.heads = nn.ModuleList(nn.Linear(width, size) for size in self.head_sizes)

    def forward(self, phi: Tensor, phi_next: Tensor) -> list[Tensor]:
        x = self.trunk(torch.cat([phi, phi_next], dim=-1))
        return [head(x) for head in self.heads]


class RCMAttention(nn.Module):
    """Attention weights W of eqs. 1–2 (and eq. 5): softmax over the D features of Linear(D → D)(x).

    x is what the weighting is conditioned on: φ_{t+1} for RCM, the previous squared error for LTP. The weights sum
    to 1 over the features (so the loss focuses on a feature subspace); ``unit_mean=True`` scales them by D so that
    their mean is 1 and a weighted MSE has the scale of an unweighted one (not in the paper).
    """

    def __init__(self, feature_size: int, unit_mean: bool = False) -> None:
        super().__init__()
        self.linear = nn.Linear(feature_size, feature_size)
        self.unit_mean = unit_mean

    def forward(self, x: Tensor) -> Tensor:
        weights = torch.softmax(self.linear(x), dim=-1)
        return weights * x.shape[-1] if self.unit_mean else weights


def rcm_forward_loss(pred: Tensor, target: Tensor, attention: Tensor, mask: Tensor | None) -> Tensor:
    """Eqs. 1–2: J = (1/D) eᵀe with e = √W (φ − φ̂), i.e. mean_j W_j (φ_j − φ̂_j)², averaged over unmasked samples.

    pred, target, attention: (…, D); mask: (…). The caller decides whether ``target`` is detached.
    """
    return masked_mean((attention * (target - pred) ** 2).mean(-1), mask)


def _heads(actions_index: Tensor | Sequence[Tensor]) -> list[Tensor]:
    if isinstance(actions_index, Tensor):
        return list(actions_index.long().unbind(-1))
    return [a.long() for a in actions_index]


def icm_losses(phi: Tensor, actions_onehot: Tensor, actions_index: Tensor | Sequence[Tensor],
               forward: ForwardModel, inverse: InverseModel, mask: Tensor | None,
               attention: RCMAttention | None = None, detach_target: bool = True) -> dict[str, Tensor]:
    """ICM forward and inverse losses over a rollout (the RCM forward loss when ``attention`` is given).

    phi: (T+1, N, D); actions_onehot: (T, N, A); actions_index: (T, N, H) or H tensors (T, N); mask: (T, N).
    forward = masked mean over (t, agent) of mean_j (f(φ_t, a_t) − φ_{t+1})_j², or with RCM the same weighted by
    attention(φ_{t+1}) (eqs. 1–2). The target φ_{t+1} — also the attention's input — is detached by default (see the
    module docstring); φ_t is not, so the encoder is trained through the forward model's input.
    inverse = masked mean over (t, agent) of the mean over heads of the cross-entropy of g(φ_t, φ_{t+1}) against
    a_t; neither φ is detached (this is what trains the encoder in ICM).
    """
    steps = actions_onehot.shape[0]
    if phi.shape[0] != steps + 1:
        raise ValueError(f"phi has {phi.shape[0]} steps, expected T+1 = {steps + 1}")
    phi_t, phi_next = phi[:-1], phi[1:]
    target = phi_next.detach() if detach_target else phi_next
    pred = forward(phi_t, actions_onehot)
    if attention is None:
        forward_loss = masked_mean(((pred - target) ** 2).mean(-1), mask)
    else:
        forward_loss = rcm_forward_loss(pred, target, attention(target), mask)

    logits = inverse(phi_t, phi_next)
    heads = _heads(actions_index)
    if len(heads) != len(logits):
        raise ValueError(f"{len(heads)} action heads given, the inverse model has {len(logits)}")
    valid = torch.ones(phi_t.shape[:-1], dtype=torch.bool, device=phi.device) if mask is None else mask.bool()
    ce = []
    for head_logits, index in zip(logits, heads):
        index = torch.where(valid & (index >= 0), index, 0)   # masked agents may carry padding indices
        flat = F.cross_entropy(head_logits.reshape(-1, head_logits.shape[-1]), index.reshape(-1), reduction="none")
        ce.append(flat.reshape(index.shape))
    inverse_loss = masked_mean(torch.stack(ce).mean(0), valid)
    return {"forward": forward_loss, "inverse": inverse_loss}


# ---------------------------------------------------------------------------------------------------------------
# Long-Term Prediction (eqs. 3–6)

class LongTermPredictor(nn.Module):
    """``horizon`` separate forward nets that feed their own predictions back (eq. 3):
    φ̂_1 = f_1(φ_0, a_0), φ̂_k = f_k(φ̂_{k−1}, a_{k−1}), with the actions actually taken.

    Separate MLPs rather than one RNN (the paper: "so we do not suffer from slower RNNs"); errors accumulate along
    the chain, which the attention weighting of ``ltp_loss`` is meant to compensate.
    """

    def __init__(self, feature_size: int, action_size: int, horizon: int, hidden: int = 140) -> None:
        super().__init__()
        if horizon < 1:
            raise ValueError("horizon must be at least 1")
        self.nets = nn.ModuleList(ForwardModel(feature_size, action_size, hidden) for _ in range(horizon))

    @property
    def horizon(self) -> int:
        return len(self.nets)

    def forward(self, phi0: Tensor, actions_onehot: Tensor) -> Tensor:
        """phi0: (N, D); actions_onehot: (T, N, A) → (min(horizon, T), N, D) predictions φ̂_1, φ̂_2, …"""
        steps = min(self.horizon, actions_onehot.shape[0])
        predictions, x = [], phi0
        for k in range(steps):
            x = self.nets[k](x, actions_onehot[k])
            predictions.append(x)
        if not predictions:
            return phi0.new_zeros((0, *phi0.shape))
        return torch.stack(predictions)


class LTPResult(NamedTuple):
    loss: Tensor       # scalar J_LTP with gradient; callers weight it and add it to the optimised loss
    weighted: Tensor   # (K,) detached J_LTP,i per horizon i = 1..K, for logging
    mse: Tensor        # (K,) detached unweighted masked MSE per horizon, for logging


def ltp_loss(phi: Tensor, actions_onehot: Tensor, predictor: LongTermPredictor, attention_layer: RCMAttention,
             mask: Tensor | None, detach_target: bool = True, detach_weight_input: bool = False) -> LTPResult:
    """Eqs. 4–6: J_LTP = (1/K) Σ_{i=1..K} J_i, J_i = mean over valid agents of mean_j w_ij (φ_ij − φ̂_ij)², with
    w_1 = 1 and w_i = attention_layer(e_{i−1}), e_{i−1} = (φ_{i−1} − φ̂_{i−1})² elementwise; K = min(horizon, T).

    phi: (T+1, N, D); actions_onehot: (T, N, A); mask: (T, N). Prediction i is scored for an agent only if the mask
    is True at all of steps 0..i−1 (its chain of transitions). Unlike DynEnv at HEAD, which only logged it, the loss
    is returned for the caller to optimise. See the module docstring for the reading of each equation.
    """
    steps = actions_onehot.shape[0]
    if phi.shape[0] != steps + 1:
        raise ValueError(f"phi has {phi.shape[0]} steps, expected T+1 = {steps + 1}")
    predictions = predictor(phi[0], actions_onehot)
    k_max = predictions.shape[0]
    if k_max == 0:
        zero = phi.new_zeros(())
        return LTPResult(zero, phi.new_zeros((0,)), phi.new_zeros((0,)))
    target = phi[1:k_max + 1]
    if detach_target:
        target = target.detach()
    if mask is None:
        mask = torch.ones((steps, phi.shape[1]), dtype=torch.bool, device=phi.device)
    valid = torch.cumprod(mask[:k_max].to(torch.int64), dim=0).bool()     # (K, N)
    errors = (target - predictions) ** 2                                     # e_i, (K, N, D)
    terms, mses = [], []
    for i in range(k_max):
        if i == 0:
            weighted = errors[0]                                             # w_1 = 1
        else:
            previous = errors[i - 1].detach() if detach_weight_input else errors[i - 1]
            weighted = attention_layer(previous) * errors[i]
        terms.append(masked_mean(weighted.mean(-1), valid[i]))
        mses.append(masked_mean(errors[i].mean(-1), valid[i]).detach())
    per_horizon = torch.stack(terms)
    return LTPResult(per_horizon.sum() / k_max, per_horizon.detach(), torch.stack(mses))


# ---------------------------------------------------------------------------------------------------------------
# Localization

def pose_features(x: Tensor, y: Tensor, body_angle: Tensor, head_angle: Tensor) -> Tensor:
    """The localization target [x, y, cos(θ+h), sin(θ+h), cos h, sin h] (θ body heading, h head angle relative to
    the body): two orientations as unit vectors, so the regression has no 2π wrap-around."""
    gaze = body_angle + head_angle
    return torch.stack([x, y, torch.cos(gaze), torch.sin(gaze), torch.cos(head_angle), torch.sin(head_angle)], -1)


def localization_loss(pose_pred: Tensor, pose_true: Tensor, mask: Tensor | None = None) -> Tensor:
    """Self-supervised localization: the sum over the pose components of their MSE (as DynEnv's sum of 6 MSEs),
    i.e. masked mean over agents of Σ_c (pred_c − true_c)². pose_*: (…, 6) (any L); mask: (…)."""
    return masked_mean(((pose_pred - pose_true.detach()) ** 2).sum(-1), mask)


# ---------------------------------------------------------------------------------------------------------------
# Reconstruction with field-fixed anchors

def _numpy(x: Tensor | np.ndarray | Sequence[Any]) -> np.ndarray:
    if isinstance(x, Tensor):
        array: np.ndarray = x.detach().cpu().numpy()
        return array
    converted: np.ndarray = np.asarray(x)
    return converted


def _assignment_costs(anchors: np.ndarray, targets: np.ndarray, seen: np.ndarray) -> np.ndarray:
    """(M, S) squared distances from each target to each anchor; 0 for unseen targets (they may take any slot)."""
    cost: np.ndarray = ((targets[:, None, :2] - anchors[None, :, :2]) ** 2).sum(-1)
    cost[~seen.astype(bool)] = 0.0
    return cost


def assign_slots(anchors: Tensor | np.ndarray, targets: Tensor | np.ndarray, seen: Tensor | np.ndarray) -> Tensor:
    """Hungarian assignment of targets to anchor slots minimising the summed squared target–anchor distance.

    anchors: (S, 2); targets: (M, ≥2), x and y first; seen: (M,) bool; M ≤ S. Returns a (M,) long tensor: the slot
    of each target (distinct slots). Unseen targets cost 0 everywhere, so the seen targets get the optimal slots and
    the unseen ones fill some of the rest.
    """
    anchors_np, targets_np, seen_np = _numpy(anchors), _numpy(targets), _numpy(seen)
    slots, count = anchors_np.shape[0], targets_np.shape[0]
    if count > slots:
        raise ValueError(f"{count} targets for {slots} slots")
    perm = np.zeros(count, dtype=np.int64)
    if count:
        rows, cols = linear_sum_assignment(_assignment_costs(anchors_np, targets_np, seen_np))
        perm[rows] = cols
    return torch.from_numpy(perm)


def assign_slots_batch(anchors: np.ndarray, targets: np.ndarray, seen: np.ndarray) -> np.ndarray:
    """``assign_slots`` for a batch at once: anchors (S, 2), targets (B, M, ≥2), seen (B, M) → (B, M) int64.

    Why: the reconstruction loss assigns every (step, robot) of a rollout — hundreds of tiny problems per update,
    where a Python loop over ``linear_sum_assignment`` costs more than the network's backward pass. With few slots
    every injective map is enumerated once (S!/(S−M)! of them, 24 for 3 robots in 4 slots) and all problems are
    solved by one argmin; larger problems fall back to the Hungarian method per row. Ties go to the first map in
    lexicographic order, as ``brute_force_assignment``."""
    batch, count = targets.shape[:2]
    slots = anchors.shape[0]
    if count > slots:
        raise ValueError(f"{count} targets for {slots} slots")
    if count == 0:
        return np.zeros((batch, 0), np.int64)
    if math.perm(slots, count) > 5040:
        return np.stack([_numpy(assign_slots(anchors, targets[b], seen[b])) for b in range(batch)])
    cost = ((targets[:, :, None, :2] - anchors[None, None, :, :2]) ** 2).sum(-1)          # (B, M, S)
    cost = np.where(seen.astype(bool)[:, :, None], cost, 0.0)
    maps = np.array(list(itertools.permutations(range(slots), count)), np.int64)          # (P, M)
    totals = cost[:, np.arange(count)[None, :], maps].sum(-1)                              # (B, P)
    best: np.ndarray = maps[np.argmin(totals, axis=1)]
    return best


def assignment_cost(anchors: Tensor | np.ndarray, targets: Tensor | np.ndarray, seen: Tensor | np.ndarray,
                    perm: Tensor | np.ndarray) -> float:
    """Summed squared distance of the seen targets to their slots under ``perm`` (what the assignment minimises)."""
    cost = _assignment_costs(_numpy(anchors), _numpy(targets), _numpy(seen))
    perm_np = _numpy(perm).astype(np.int64)
    return float(cost[np.arange(len(perm_np)), perm_np].sum())


def brute_force_assignment(anchors: Tensor | np.ndarray, targets: Tensor | np.ndarray,
                           seen: Tensor | np.ndarray) -> Tensor:
    """Exhaustive search over all injective target → slot maps (reference for ``assign_slots``; small S only)."""
    anchors_np, targets_np, seen_np = _numpy(anchors), _numpy(targets), _numpy(seen)
    cost = _assignment_costs(anchors_np, targets_np, seen_np)
    count = targets_np.shape[0]
    best, best_cost = None, np.inf
    for perm in itertools.permutations(range(anchors_np.shape[0]), count):
        total = cost[np.arange(count), list(perm)].sum()
        if total < best_cost:
            best, best_cost = perm, total
    if best is None:
        raise ValueError(f"{count} targets for {anchors_np.shape[0]} slots")
    return torch.tensor(best, dtype=torch.long)


def reconstruction_loss(pred_slots: Tensor, pred_conf: Tensor, targets: Tensor, seen: Tensor,
                        anchors: Tensor | Sequence[Sequence[float]] = ANCHORS, ignore_radius: float = 0.4,
                        mask: Tensor | None = None, present: Tensor | None = None,
                        binary_fields: Sequence[int] = ()) -> dict[str, Tensor]:
    """Anchor-based reconstruction of the dynamic objects of one class, YOLO-style (section 4.3).

    pred_slots: (…, S, K) absolute predictions per slot (x, y first; the anchors only decide which slot answers for
    which object, they are not offsets); pred_conf: (…, S) confidence logits; targets: (…, M, K); seen: (…, M) bool,
    the objects the agent has seen (so it can be asked to reconstruct them); anchors: (S, 2); mask: (…) trainable
    agents (default all); present: (…, M) bool, which target rows are real objects (default all; False for padding).

    Returns dict(position = MSE of x, y over the (agent, seen target) pairs at their assigned slots;
    fields = MSE of the other fields there, plus the mean BCE-with-logits of the fields listed in ``binary_fields``
    (indices into K, targets in {0, 1}); confidence = mean BCE-with-logits over the slots, target 1 on slots assigned
    to seen targets, 0 on the others, except that an unassigned slot whose predicted x, y lies within
    ``ignore_radius`` of a present object the agent has NOT seen is left out — it may be a correct guess about
    something out of view, so it is no clear false positive. A second slot next to a *seen* object is a
    duplicate (that object already has its assigned slot) and is pushed to 0: DynEnv exempted slots near any
    object, so duplicates were never penalised and its precision counted them as hits).
    ``ignore_radius`` is in the units of the positions (DynEnv's 0.4 was in normalised units, ≈ 2.1 m).
    """
    slots, fields = pred_slots.shape[-2:]
    count = targets.shape[-2]
    batch_shape = pred_slots.shape[:-2]
    batch = math.prod(batch_shape)
    flat_pred = pred_slots.reshape(batch, slots, fields)
    flat_conf = pred_conf.reshape(batch, slots)
    flat_targets = targets.reshape(batch, count, fields).to(pred_slots.dtype)
    device = pred_slots.device
    agents = (torch.ones(batch_shape, dtype=torch.bool, device=device) if mask is None else mask.bool()).reshape(batch)
    real = (torch.ones(seen.shape, dtype=torch.bool, device=device) if present is None else present.bool())
    real = real.reshape(batch, count)
    known = seen.bool().reshape(batch, count) & real
    anchors_np = _numpy(anchors).astype(np.float64)
    if anchors_np.shape != (slots, 2):
        raise ValueError(f"anchors must be ({slots}, 2), got {anchors_np.shape}")

    slot_of = torch.from_numpy(assign_slots_batch(anchors_np, _numpy(flat_targets), _numpy(known))).to(device)

    b_idx, m_idx = (known & agents[:, None]).nonzero(as_tuple=True)
    s_idx = slot_of[b_idx, m_idx]
    matched, truth = flat_pred[b_idx, s_idx], flat_targets[b_idx, m_idx]          # (P, K) each
    position = _mean_or_zero((matched[:, :2] - truth[:, :2]) ** 2)
    binary = sorted(set(binary_fields))
    if any(k < 2 or k >= fields for k in binary):
        raise ValueError(f"binary_fields must index the non-position fields 2..{fields - 1}")
    continuous = [k for k in range(2, fields) if k not in binary]
    field_loss = _mean_or_zero((matched[:, continuous] - truth[:, continuous]) ** 2)
    if binary:
        field_loss = field_loss + _mean_or_zero(F.binary_cross_entropy_with_logits(
            matched[:, binary], truth[:, binary], reduction="none"))

    positive = torch.zeros((batch, slots), dtype=torch.bool, device=device)
    positive[b_idx, s_idx] = True
    with torch.no_grad():
        distance2 = ((flat_pred[:, :, None, :2] - flat_targets[:, None, :, :2]) ** 2).sum(-1)   # (B, S, M)
        near = ((distance2 < ignore_radius ** 2) & (real & ~known)[:, None, :]).any(-1)
    scored = agents[:, None] & (positive | ~near)
    bce = F.binary_cross_entropy_with_logits(flat_conf, positive.to(flat_conf.dtype), reduction="none")
    return {"position": position, "fields": field_loss, "confidence": masked_mean(bce, scored)}
