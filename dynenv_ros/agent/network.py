"""The agent of the DynEnv paper (section 4, Figure 6), rebuilt: per-class embeddings, intratemporal self-attention
and Recurrent Temporal Attention over the vision frames of a motion period, confidence-weighted pooling, a
localization stream and an object stream with LSTMs across periods, one actor head per action dimension (the
continuous head turn included) and a critic.

The recurrent state is explicit (a tuple of four (B, D) tensors in and out) so that a policy node can keep one
per robot and an ONNX export can carry it as inputs and outputs. ``DynEnvAgent.forward`` runs one motion period of
B robots (acting); ``forward_sequence`` runs T periods of B robots (a rollout, for training) with episode resets,
giving what T ``forward`` calls give.

Built for speed on a CPU core without changing the function (the tests compare outputs and gradients with the
dense, literal computation): each detection goes through its own class's embedding only, padded slots are skipped,
periods are bucketed by how many slots they use and cut to that, the single-head attentions run in a folded form
(half the matrix work), and in ``forward_sequence`` the embeddings and the RTA see all T·B periods at once — only
the LSTM cells step through time. Figures: docs/benchmarks.md, "Agent forward/backward (issue 11)".

Two scenarios (``DynEnvAgent(scenario=…)``), one architecture:

- ``soccer`` (the default; exactly the network above: same parameters, same seeded initialisation, same outputs):
  landmarks and objects streams over F = 5 frames, the pose head, walk/turn/kick/head actor heads, the
  reconstruction head.
- ``driving`` (the paper's Driving agent, docs/original.md §9): the static stream takes the car's SELF row and the
  lanes, the dynamic one cars, pedestrians, obstacles and class-less false positives, each with its own class table
  (``inputs.agent_inputs``); one frame per period, so there is **no temporal attention** — the RTA is the
  intratemporal self-attention and the pooling only (the paper's nTime = 1: its temporal loop never runs), and the
  network has no temporal-attention weights; a period of more than one frame is refused. Actor heads: two
  categorical heads of 3 (``action_mode='discrete'``, the original's MultiDiscrete([3, 3])) or one clipped 3-d
  Gaussian over [throttle, brake, steering / limit] (``'continuous'``; ``driving.agent_actions``). **No
  localization or reconstruction heads**: their targets (the car's map pose; the other road users' positions) are
  not built for driving (``envs/learning_targets.py`` is soccer's), and an untrained pose head feeding the object
  stream (the paper's predictor of 4) would be a fixed random projection; the object stream takes the self state
  only. ``pose``, ``ball`` and ``robots`` of its steps are None.

**The pose estimate as an input** (soccer, ``uses_pose=True``; a run with ``localization: estimate``): the self
state both streams take before their LSTMs ends with the robot's self-localization estimate (``pose_estimate``, 7
values, ``inputs.side_inputs(..., pose=True)``), scaled inside the network (``inputs.encode_pose``); the two
streams' input transforms are 7 columns wider, nothing else changes. ``uses_pose=False`` (the default, every
earlier checkpoint) is the network above, parameter for parameter.
"""
from __future__ import annotations

import math
from typing import Any, Callable, cast
from dataclasses import dataclass

import numpy as np
import torch
from torch import nn
from torch.distributions import Categorical, Normal

from dynenv_ros.core.action_draws import Gaussian, draw_actions
from dynenv_ros.driving import agent_actions as driving_actions
from dynenv_ros.agent.inputs import (ACTION_ENCODING, NUM_CLASSES, POSE_INPUT, PROPRIOCEPTION, SCENARIOS, StreamBatch,
                                     agent_inputs, encode_pose)
from dynenv_ros.envs.padded_layout import FEATURES

POSE_SIZE = 6            # [x, y, cos(θ+h), sin(θ+h), cos h, sin h] in the team frame
State = tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]
# EmbedBlock's layers as its forward unpacks them (for mypy: an nn.Sequential iterates as plain Modules)
_EmbedLayers = tuple[nn.Linear, nn.Module, nn.LayerNorm, nn.Linear, nn.Module, nn.LayerNorm]
_Folded = tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]     # SingleHeadAttention.folded()


class EmbedBlock(nn.Module):
    """Linear → LeakyReLU → LayerNorm, twice (the paper's per-class embedding)."""

    def __init__(self, in_features: int, size: int, hidden: int = 32) -> None:
        super().__init__()
        self.net = nn.Sequential(nn.Linear(in_features, hidden, bias=False), nn.LeakyReLU(0.1), nn.LayerNorm(hidden),
                                 nn.Linear(hidden, size, bias=False), nn.LeakyReLU(0.1), nn.LayerNorm(size))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        # ``self.net(x)`` written out with its layers' parameters: the same ops without six module calls (their
        # Python overhead is most of the cost at the few hundred rows a class has in one batch)
        first, _, first_norm, second, _, second_norm = cast(_EmbedLayers, self.net)
        functional = nn.functional
        x = functional.layer_norm(functional.leaky_relu(functional.linear(x, first.weight), 0.1),
                                  first_norm.normalized_shape, first_norm.weight, first_norm.bias, first_norm.eps)
        return functional.layer_norm(functional.leaky_relu(functional.linear(x, second.weight), 0.1),
                                     second_norm.normalized_shape, second_norm.weight, second_norm.bias,
                                     second_norm.eps)


def _tracing() -> bool:
    """True while the ONNX exporter traces the model: the paths below that read data-dependent sizes into Python
    (row counts per class, the number of used slots) then take the equivalent graph-only form."""
    return torch.jit.is_tracing() or torch.onnx.is_in_onnx_export()


class ClassEmbedding(nn.Module):
    """One EmbedBlock per object class, all with the same output size; each row goes through its own class's block
    only, and a padded row (``mask`` True) through none: it embeds to zero.

    Why sparse: running every class's block on every slot and keeping one (the obvious batched form) is C× the
    needed work, padding included. A padded slot's embedding never reaches an output — it is a masked key, its
    query's output is zeroed, and a slot empty in this frame but filled earlier enters the temporal attention with
    a zero query whatever its embedding — so zero is as good as anything there, and gradients are the dense form's.
    In eager mode the real rows are sorted by class once and each class present runs its block on one contiguous
    slice; under the ONNX tracer (no Python sizes) each class selects its rows with ``nonzero``."""

    def __init__(self, size: int, classes: int = NUM_CLASSES) -> None:
        super().__init__()
        self.blocks = nn.ModuleList(EmbedBlock(FEATURES, size) for _ in range(classes))
        self.size = size

    def forward(self, features: torch.Tensor, kind: torch.Tensor, mask: torch.Tensor | None = None
                ) -> torch.Tensor:
        """features (..., FEATURES), kind (...) class index, mask (...) True = padded → (..., size)."""
        rows = features.reshape(-1, features.shape[-1])
        flat_kind = kind.reshape(-1)
        if mask is not None:
            flat_kind = flat_kind.masked_fill(mask.reshape(-1), -1)
        if _tracing():
            out = rows.new_zeros((rows.shape[0], self.size))
            for index, block in enumerate(self.blocks):
                selected = torch.nonzero(flat_kind == index).squeeze(1)
                out = out.index_put((selected,), block(rows.index_select(0, selected)))
            return out.reshape(*kind.shape, self.size)
        counts = torch.bincount(flat_kind + 1, minlength=len(self.blocks) + 1).tolist()    # [padded, class 0, …]
        if len(counts) > len(self.blocks) + 1:
            raise ValueError(f"class index outside 0..{len(self.blocks) - 1} on an unpadded row")
        padded = counts[0]
        out = rows.new_zeros((rows.shape[0], self.size))
        if padded < rows.shape[0]:
            order = torch.argsort(flat_kind, stable=True)[padded:]            # real rows, grouped by class
            parts = rows.index_select(0, order).split(counts[1:])
            embedded = torch.cat([block(part) for block, part in zip(self.blocks, parts) if part.shape[0]])
            out = out.index_copy(0, order, embedded)
        return out.reshape(*kind.shape, self.size)


def trim(batch: StreamBatch) -> StreamBatch:
    """The stream without its trailing slots that are padded in every batch entry and frame (at least one slot is
    kept, so no axis becomes empty).

    Exact: a slot padded in every frame is never filled so far, so the RTA's carried mask zeroes it, excludes it as
    a key and leaves it out of the pooling at every frame — it never changes an output. Slots padded only in some
    frames or entries are kept (they can hold a summary from an earlier frame). Why: fixed maxima are sized for the
    worst frame, a typical batch fills half of them, and the attention's cost grows with the slots."""
    mask = batch.mask
    slots = mask.shape[-1]
    if _tracing():
        position = torch.arange(1, slots + 1, dtype=torch.int64, device=mask.device)
        used = torch.clamp((position * (~mask).to(torch.int64)).amax(), min=1)
        keep = torch.arange(used, device=mask.device)  # type: ignore[call-overload]  # (a 0-d tensor: traced)
        last = mask.dim() - 1
        return StreamBatch(batch.features.index_select(last, keep), batch.kind.index_select(last, keep),
                           mask.index_select(last, keep))
    filled = torch.nonzero((~mask).reshape(-1, slots).any(0))
    kept = int(filled[-1]) + 1 if filled.numel() else 1
    if kept == slots:
        return batch
    return StreamBatch(batch.features[..., :kept, :], batch.kind[..., :kept], mask[..., :kept])


class _ShortRowSoftmax(torch.autograd.Function):
    """Softmax over the last axis, written out: a max shift, exp, a row sum, a division; backward y·(g − Σ g·y).

    Why: ``torch.softmax`` on CPU handles a short last axis (the attention's N + 1 ≤ 13 keys) row by row, about 5x
    slower forward and 3x slower forward + backward than these whole-tensor element-wise passes (docs/benchmarks.md,
    "The learner against its FLOP limit"). The same function up to float rounding (a masked key, −inf, gets exactly
    0; the bias slot is never masked, so no row is all −inf)."""

    @staticmethod
    def forward(ctx: Any, scores: torch.Tensor) -> torch.Tensor:
        weights = (scores - scores.amax(-1, keepdim=True)).exp_()
        weights = weights.div_(weights.sum(-1, keepdim=True))
        ctx.save_for_backward(weights)
        return weights

    @staticmethod
    def backward(ctx: Any, grad: torch.Tensor) -> torch.Tensor:
        (weights,) = ctx.saved_tensors
        return cast(torch.Tensor, weights * (grad - (grad * weights).sum(-1, keepdim=True)))


def short_row_softmax(scores: torch.Tensor) -> torch.Tensor:
    """Softmax over the last axis (``_ShortRowSoftmax``); under the ONNX tracer torch's own (one Softmax node)."""
    if _tracing():
        return torch.softmax(scores, dim=-1)
    return cast(torch.Tensor, _ShortRowSoftmax.apply(scores))  # type: ignore[no-untyped-call]


def _bias_slot(x: torch.Tensor) -> torch.Tensor:
    """The extra key slot [0, …, 0, 1] of ``_with_bias_slot``, (1, 1, D + 1), to build once per call."""
    return nn.functional.pad(x.new_ones(1, 1, 1), (x.shape[-1], 0))


def _with_bias_slot(x: torch.Tensor, slot: torch.Tensor | None = None) -> torch.Tensor:
    """(S, N, D) → (S, N + 1, D + 1): each row with a 0 appended, then one more row [0, …, 0, 1] — the keys (and
    values) of ``SingleHeadAttention``'s folded form, whose last slot stands for the learned bias key/value.
    ``slot``: ``_bias_slot(x)`` where the caller already has it."""
    slot = _bias_slot(x) if slot is None else slot
    return torch.cat([nn.functional.pad(x, (0, 1)), slot.expand(x.shape[0], 1, slot.shape[-1])], dim=1)


class SingleHeadAttention(nn.Module):
    """``nn.MultiheadAttention(size, 1, add_bias_kv=True, batch_first=True)`` — the same parameters (names, shapes,
    initialisation: the same seed gives the same weights, checkpoints load either way) and the same function —
    computed in a folded form that needs half the work.

    The module's function, for a query x_i and keys/values y_j (padded ones excluded) plus the learned bias key
    b_k/value b_v: q_i = W_q x_i + c_q, k_j = W_k y_j + c_k, v_j = W_v y_j + c_v, p = softmax_j(s·q_i·k_j, with the
    bias key's score s·q_i·b_k), out_i = W_o(Σ_j p_j v_j + p_b b_v) + c_o, s = 1/√D. Subtracting s·q_i·c_k from
    every score (a softmax does not change) and using Σ_j p_j + p_b = 1:

        scores: s·q_i·k_j → (s W_kᵀ q_i) · y_j,      bias key: s·q_i·(b_k − c_k)
        out_i  = W_o [W_v | b_v − c_v] [Σ_j p_j y_j ; p_b] + W_o c_v + c_o

    so with keys = values = [y_j ; 0] plus one extra slot [0 ; 1] for the bias (``_with_bias_slot``), the query is
    one (D+1)×D projection of x_i and the output one D×(D+1) projection of the attention's result: no key or value
    projections at all (the attention reads the inputs themselves), and the products of the weight matrices (D×D,
    negligible) are formed once per forward pass. Exact up to float rounding (the tests hold outputs and gradients
    to the unfolded computation). No dropout, no attention weights returned (the RTA needs neither).

    The attention itself is baddbmm (scores plus the additive key mask) → softmax (``short_row_softmax``) → bmm,
    which measured faster on one CPU core than ``scaled_dot_product_attention`` at these sizes, forward and backward
    (docs/benchmarks.md, "Agent forward/backward"); it is also a handful of plain ONNX nodes."""

    def __init__(self, size: int) -> None:
        super().__init__()
        self.embed_dim = size
        self.scale = 1.0 / math.sqrt(size)
        # registration order and initialisation as nn.MultiheadAttention's (the same seed gives the same weights)
        self.in_proj_weight = nn.Parameter(torch.empty(3 * size, size))
        self.in_proj_bias = nn.Parameter(torch.empty(3 * size))
        self.out_proj = nn.Linear(size, size)
        self.bias_k = nn.Parameter(torch.empty(1, 1, size))
        self.bias_v = nn.Parameter(torch.empty(1, 1, size))
        nn.init.xavier_uniform_(self.in_proj_weight)
        nn.init.constant_(self.in_proj_bias, 0.0)
        nn.init.constant_(self.out_proj.bias, 0.0)
        nn.init.xavier_normal_(self.bias_k)
        nn.init.xavier_normal_(self.bias_v)

    def folded(self) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
        """(query weight (D+1, D), query bias (D+1), output weight (D, D+1), output bias (D)) of the folded form."""
        D = self.embed_dim
        w_q, w_k, w_v = self.in_proj_weight.split(D)
        c_q, c_k, c_v = self.in_proj_bias.split(D)
        keys = torch.cat([w_k.t(), (self.bias_k.reshape(1, D) - c_k)], dim=0) * self.scale     # (D+1, D)
        values = torch.cat([w_v, (self.bias_v.reshape(D, 1) - c_v.unsqueeze(1))], dim=1)       # (D, D+1)
        return (keys @ w_q, keys @ c_q, self.out_proj.weight @ values,
                self.out_proj.weight @ c_v + self.out_proj.bias)

    def key_mask(self, key_padding_mask: torch.Tensor) -> torch.Tensor:
        """(..., 1, N + 1) additive mask of key_padding_mask (..., N): −inf on padded keys, 0 on the others and on
        the bias slot (never padded, so no query has all its keys masked)."""
        padded = torch.cat([key_padding_mask, torch.zeros_like(key_padding_mask[..., :1])], dim=-1)
        additive = torch.zeros(padded.shape, dtype=self.bias_k.dtype, device=padded.device).masked_fill(padded, float("-inf"))
        return additive.unsqueeze(-2)

    @staticmethod
    def attend(query: torch.Tensor, keys: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        """query (S, L, D+1) folded, keys (S, N+1, D+1) from ``_with_bias_slot``, mask (S, 1, N+1) from
        ``key_mask`` → (S, L, D+1), the attention-weighted keys (input of the folded output projection)."""
        return torch.bmm(short_row_softmax(torch.baddbmm(mask, query, keys.transpose(1, 2))), keys)

    def forward(self, query: torch.Tensor, key: torch.Tensor | None = None,
                key_padding_mask: torch.Tensor | None = None) -> torch.Tensor:
        """query (S, L, D), key = value (S, N, D) (None: self-attention), key_padding_mask (S, N) True = padded →
        (S, L, D), what ``nn.MultiheadAttention`` gives (its first output)."""
        key = query if key is None else key
        if key_padding_mask is None:
            key_padding_mask = torch.zeros(key.shape[:2], dtype=torch.bool, device=key.device)
        w_query, b_query, w_out, b_out = self.folded()
        attended = self.attend(nn.functional.linear(query, w_query, b_query), _with_bias_slot(key),
                               self.key_mask(key_padding_mask))
        return nn.functional.linear(attended, w_out, b_out)


class RecurrentTemporalAttention(nn.Module):
    """Self-attention over the objects of each frame, then attention from each frame's objects to the running
    summary of the earlier frames (fed back, Figure 4), then confidence-weighted pooling.

    The summary has one slot per detection slot: summary_t = LayerNorm(A_t + attention(A_t, summary_{t−1})), A_t the
    frame's self-attended objects (zero on its padded slots). DynEnv had LayerNorm(attention(...)) without the A_t
    term; then every value the attention mixes descends from frame 0 and later frames only steer the weights, so
    the residual lets the newest detections themselves reach the output.

    Mask rule: a summary slot is valid once it has held a detection in ANY frame so far (padded_so_far =
    padded_so_far & padded_t, as DynEnv's M = M ∧ mask_t); only slots never filled yet are excluded as keys and left
    out of the pooling (what such a slot holds never reaches an output, so it is not zeroed). A slot that is empty
    in the current frame but was filled earlier keeps a summary (its query is zero, so it becomes the attention's
    read of the earlier summary). Why: the summary is the memory of the whole motion period; masking it by the
    current frame alone made the pooled output zero whenever the period's last frame was empty, whatever the
    earlier frames saw (the object stream, 2v2 under a random policy: 12–15 % of periods have an empty last frame
    after a ball or robot was seen earlier in the period).

    Both attentions carry a learned bias key/value, so a frame without detections still has one key to attend to.
    Pooling: Σ c_i·x_i / (1 + Σ c_i), c_i = sigmoid(w·x_i). Dividing by the confidences (not by the count, as DynEnv
    did) makes the output independent of how many low-confidence detections are present; the +1 keeps an empty or
    all-doubtful frame at a small, finite output instead of dividing by zero.

    Nothing here depends on earlier motion periods, so a whole rollout (T·B periods) goes through in one batch.
    """

    temporal_attention: SingleHeadAttention | None     # None without the temporal part (declared for mypy)
    norm: nn.LayerNorm | None

    def __init__(self, size: int, temporal: bool = True) -> None:
        super().__init__()
        self.object_attention = SingleHeadAttention(size)
        if temporal:        # (one frame per period, driving: no temporal attention and no weights for it)
            self.temporal_attention = SingleHeadAttention(size)
            self.norm = nn.LayerNorm(size)
        else:
            self.temporal_attention = self.norm = None
        self.confidence = nn.Linear(size, 1)

    def forward(self, x: torch.Tensor, mask: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """x (B, F, N, D), mask (B, F, N) True = padded → pooled (B, D), confidences (B, N) of the final summary's
        slots (0 on slots no frame of the period filled)."""
        return self.frames_first(x.transpose(0, 1), mask.transpose(0, 1))

    def folded(self) -> tuple[_Folded, _Folded | None]:
        """Both attentions' folded weights (``SingleHeadAttention.folded``), to form once per forward pass."""
        temporal = self.temporal_attention
        return self.object_attention.folded(), (temporal.folded() if temporal is not None else None)

    def frames_first(self, x: torch.Tensor, mask: torch.Tensor,
                     folded: tuple[_Folded, _Folded | None] | None = None
                     ) -> tuple[torch.Tensor, torch.Tensor]:
        """``forward`` with the frame axis first: x (F, B, N, D), mask (F, B, N) (each frame's rows contiguous);
        ``folded``: ``self.folded()`` where the caller already has it."""
        F, B, N, D = x.shape
        if self.temporal_attention is None and not _tracing() and F != 1:     # (export_onnx checks its frames)
            raise ValueError(f"this network has no temporal attention (one vision frame per period); got {F} frames")
        linear = nn.functional.linear
        folded_object, folded_temporal = self.folded() if folded is None else folded
        padded_so_far = (~mask).long().cumsum(0) == 0      # (F, B, N): no frame up to this one filled the slot
        # additive key masks of both attentions at once: −inf on padded keys, 0 on the rest and the bias slot
        key_masks = nn.functional.pad(torch.where(torch.stack([mask, padded_so_far]), float("-inf"), 0.0),
                                      (0, 1)).to(x.dtype).unsqueeze(-2)          # (2, F, B, 1, N + 1)
        slot = _bias_slot(x)
        w_query, b_query, w_out, b_out = folded_object
        rows = x.reshape(F * B, N, D)
        attended = SingleHeadAttention.attend(linear(rows, w_query, b_query), _with_bias_slot(rows, slot),
                                              key_masks[0].reshape(F * B, 1, N + 1))
        attended = linear(attended, w_out, b_out).reshape(F, B, N, D).masked_fill(mask.unsqueeze(-1), 0.0)
        # one frame at a time (unbind, not slicing: backward then stacks the frames' gradients once instead of
        # filling a zero tensor of the whole stack for every slice)
        frames = attended.unbind(0)
        summary = frames[0]
        if len(frames) > 1:               # (one frame: nothing to attend over, the summary is the frame itself)
            w_query, b_query, w_out, b_out = cast(_Folded, folded_temporal)     # (more frames: temporal)
            temporal_masks = key_masks[1].unbind(0)
        norm = cast(nn.LayerNorm, self.norm)
        for t in range(1, len(frames)):   # (not range(1, F): under the ONNX tracer F is a traced size)
            frame = frames[t].reshape(B * N, D)
            read = SingleHeadAttention.attend(linear(frame, w_query, b_query).view(B, N, D + 1),
                                              _with_bias_slot(summary, slot), temporal_masks[t - 1])
            summary = nn.functional.layer_norm(
                torch.addmm(frame + b_out, read.reshape(B * N, D + 1), w_out.t()), norm.normalized_shape,
                norm.weight, norm.bias, norm.eps).reshape(B, N, D)
        confidence = torch.sigmoid(linear(summary, self.confidence.weight, self.confidence.bias)).squeeze(-1)
        confidence = confidence.masked_fill(padded_so_far[-1], 0.0)
        pooled = torch.bmm(confidence.unsqueeze(1), summary).squeeze(1) / (1.0 + confidence.sum(1, keepdim=True))
        return pooled, confidence


# plan_buckets' cost model, fitted on one CPU core (forward + backward of the RTA): a period padded to n slots costs
# about n·(n + _SLOT_WORK) (attention grows with n², projections and norms with n), one more bucket _BUCKET_WORK
# (its ~150 more operator calls) in the same units.
_SLOT_WORK = 28.0
_BUCKET_WORK = 3000.0


def plan_buckets(used: torch.Tensor, max_buckets: int = 3) -> list[tuple[int, int]]:
    """How to split periods sorted by their used slots (``used``, ascending) into at most ``max_buckets``
    contiguous buckets, each padded to its last (longest) period: [(periods, slots), ...], the cheapest split
    under the cost model above (dynamic programme over the distinct lengths, at most N of them)."""
    values, counts = torch.unique_consecutive(used, return_counts=True)
    v = values.cpu().numpy().astype(np.float64)      # a few dozen values: the plan is made on the CPU
    ends = np.concatenate([[0], np.cumsum(counts.cpu().numpy())])
    V = len(v)
    first, last = np.arange(V)[:, None], np.arange(V)[None, :]
    cost = (ends[last + 1] - ends[first]) * v[last] * (v[last] + _SLOT_WORK) + _BUCKET_WORK
    cost = np.where(last >= first, cost, np.inf)        # cost[a, b]: distinct lengths a..b in one bucket
    # best[k][b]: distinct lengths 0..b in k + 1 buckets; start[k][b]: where its last bucket starts
    best, starts = [cost[0]], [np.zeros(V, np.int64)]
    for _ in range(1, min(max_buckets, V)):
        options = np.concatenate([np.full((1, V), np.inf), best[-1][:-1, None] + cost[1:]])   # [a, b]: last from a
        starts.append(np.argmin(options, axis=0))
        best.append(options[starts[-1], np.arange(V)])
    k = int(np.argmin([b[V - 1] for b in best]))
    bounds, b = [V], V - 1
    while k >= 0:
        a = int(starts[k][b])
        bounds.append(a)
        b, k = a - 1, k - 1
    bounds = bounds[::-1]
    return [(int(ends[b] - ends[a]), int(v[b - 1])) for a, b in zip(bounds, bounds[1:])]


class Stream(nn.Module):
    """Embed → RTA → mix in side information → LSTM cell across motion periods → LayerNorm."""

    def __init__(self, size: int, side: int, classes: int = NUM_CLASSES, temporal: bool = True) -> None:
        super().__init__()
        self.embed = ClassEmbedding(size, classes)
        self.rta = RecurrentTemporalAttention(size, temporal)
        self.transform = nn.Sequential(nn.Linear(size + side, size), nn.LeakyReLU(0.1), nn.LayerNorm(size))
        self.lstm = nn.LSTMCell(size, size)
        self.norm = nn.LayerNorm(size)

    def encode(self, batch: StreamBatch) -> tuple[torch.Tensor, torch.Tensor]:
        """(pooled (B, D), confidence (B, N)) of a batch of periods, streams (B, F, N, ...).

        Padded work is skipped where that is exact: every detection goes through its own class's embedding only
        (``ClassEmbedding``); the periods are sorted by how many slots they use (last slot any frame filled) and
        run through the RTA in up to three buckets, each cut to its own longest period (``plan_buckets`` weighs
        the work saved against the calls added) — slots a period never fills never change its outputs (see
        ``trim``), and the RTA treats every period on its own. Confidences are padded back to N with zeros.
        Under the ONNX tracer: one bucket (``trim``), confidences left at the cut width (not exported)."""
        B, F, N = batch.mask.shape
        if _tracing():
            batch = trim(StreamBatch(batch.features.transpose(0, 1), batch.kind.transpose(0, 1),
                                     batch.mask.transpose(0, 1)))
            return self.rta.frames_first(self.embed(batch.features, batch.kind, batch.mask), batch.mask)
        if B == 0:
            return batch.features.new_zeros(0, self.embed.size), batch.features.new_zeros(0, N)
        used = ((~batch.mask).any(1) * torch.arange(1, N + 1, device=batch.mask.device)).amax(-1).clamp(min=1)       # (B,)
        used, order = torch.sort(used, stable=True)
        plan = plan_buckets(used)
        # one gather of every bucket's rows: bucket by bucket, frames first (each frame's rows contiguous for the
        # RTA), each cut to its bucket's slots
        frame_offsets = (torch.arange(F, device=used.device) * N).view(F, 1, 1)
        pieces, start = [], 0
        for count, slots in plan:
            periods = (order[start:start + count] * (F * N)).view(1, count, 1)
            pieces.append((periods + frame_offsets + torch.arange(slots, device=used.device).view(1, 1, slots)).reshape(-1))
            start += count
        index = torch.cat(pieces)
        sizes = [F * count * slots for count, slots in plan]
        mask = batch.mask.reshape(-1).index_select(0, index)
        rows = self.embed(batch.features.reshape(-1, FEATURES).index_select(0, index),
                          batch.kind.reshape(-1).index_select(0, index), mask)
        pooled_parts: list[torch.Tensor] = []
        confidence_parts: list[torch.Tensor] = []
        folded = self.rta.folded()
        for (count, slots), embedded, padded in zip(plan, rows.split(sizes), mask.split(sizes)):
            result = self.rta.frames_first(embedded.view(F, count, slots, -1), padded.view(F, count, slots), folded)
            pooled_parts.append(result[0])
            confidence_parts.append(nn.functional.pad(result[1], (0, N - slots)))
        if len(plan) == 1:
            pooled, confidence = pooled_parts[0], confidence_parts[0]
        else:
            pooled, confidence = torch.cat(pooled_parts), torch.cat(confidence_parts)
        inverse = torch.empty_like(order)
        inverse[order] = torch.arange(B, device=order.device)
        return pooled.index_select(0, inverse), confidence.index_select(0, inverse)

    def recur(self, x: torch.Tensor, state: tuple[torch.Tensor, torch.Tensor], resets: torch.Tensor | None = None
              ) -> tuple[torch.Tensor, tuple[torch.Tensor, torch.Tensor]]:
        """The LSTM cell (``self.lstm``'s weights, its maths) over T periods: x (T·B, D) period-major, state (B, D)
        each, resets (T, B) True = zero the state before that period (None: one period, no reset) → (the cell's
        outputs (T·B, D), the final state). The input projection of all T periods is one matrix product."""
        h, c = state
        B, lstm = h.shape[0], self.lstm
        gates_in = nn.functional.linear(x, lstm.weight_ih, lstm.bias_ih + lstm.bias_hh)
        outputs = []
        for t, step_in in enumerate(gates_in.split(B) if resets is not None else [gates_in]):
            if resets is not None:
                reset = resets[t].unsqueeze(-1)
                h, c = h.masked_fill(reset, 0.0), c.masked_fill(reset, 0.0)
            gates = torch.addmm(step_in, h, lstm.weight_hh.t())
            sigmoid = torch.sigmoid(gates)
            i, f, _, o = sigmoid.chunk(4, dim=1)
            c = torch.addcmul(f * c, i, torch.tanh(gates[:, 2 * lstm.hidden_size:3 * lstm.hidden_size]))
            h = o * torch.tanh(c)
            outputs.append(h)
        return (torch.cat(outputs) if len(outputs) > 1 else outputs[0]), (h, c)

    def forward(self, batch: StreamBatch, side: torch.Tensor, state: tuple[torch.Tensor, torch.Tensor]
                ) -> tuple[torch.Tensor, tuple[torch.Tensor, torch.Tensor], torch.Tensor]:
        """One period: (features (B, D), next state, confidence (B, N))."""
        pooled, confidence = self.encode(batch)
        h, state = self.recur(self.transform(torch.cat([pooled, side], dim=-1)), state)
        return self.norm(h), state, confidence


class ReconstructionHead(nn.Module):
    """Where the objects are (team frame), from the object stream: one ball slot [x, y, owner] and ``robot_slots``
    robot slots [x, y, cos, sin, teammate, fallen], each with a confidence logit. Slots are matched to objects
    through field-fixed anchors (``losses.assign_slots``); predictions are absolute positions, not offsets."""

    def __init__(self, size: int, robot_slots: int = 4) -> None:
        super().__init__()
        self.robot_slots = robot_slots
        self.net = nn.Sequential(nn.Linear(size, 2 * size), nn.LeakyReLU(0.1), nn.LayerNorm(2 * size),
                                 nn.Linear(2 * size, 4 + robot_slots * 7))

    def forward(self, features: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
        out = self.net(features)
        ball, robots = out[:, :4], out[:, 4:].reshape(-1, self.robot_slots, 7)
        return ball[:, :3], ball[:, 3], robots[..., :6], robots[..., 6]


@dataclass
class AgentStep:
    walk: torch.Tensor | None          # (B, 5) logits (soccer; None in driving, as turn, kick, head)
    turn: torch.Tensor | None          # (B, 3)
    kick: torch.Tensor | None          # (B, 3)
    head: torch.Tensor | None          # (B, 2·units+1) logits, or (B, 2) [mean, log_std] in rad per period
    value: torch.Tensor                # (B,)
    pose: torch.Tensor | None          # (B, 6) localization estimate (None in driving)
    phi: torch.Tensor                  # (B, 2D) features for the curiosity heads
    object_features: torch.Tensor      # (B, D) for the reconstruction head
    state: State
    landmark_confidence: torch.Tensor  # (B, N_landmarks)
    object_confidence: torch.Tensor    # (B, N_objects)
    ball: torch.Tensor | None = None               # (B, 3) reconstruction [x, y, owner]
    ball_confidence: torch.Tensor | None = None    # (B,) logit
    robots: torch.Tensor | None = None             # (B, S, 6) reconstruction
    robot_confidence: torch.Tensor | None = None   # (B, S) logits
    acceleration: torch.Tensor | None = None       # driving, discrete: (B, 3) logits (reverse, brake, gas)
    steering: torch.Tensor | None = None           # driving, discrete: (B, 3) logits (right, straight, left)
    command: torch.Tensor | None = None            # driving, continuous: (B, 6) [mean × 3, log_std × 3]


@dataclass
class AgentSequence(AgentStep):
    """``DynEnvAgent.forward_sequence``'s outputs: every field of ``AgentStep`` with leading (T, B) axes instead of
    (B,) — except ``state``, the recurrent state after the last period, (B, D) each."""


class DynEnvAgent(nn.Module):
    """The agent of one scenario (module docstring). Soccer: ``head_mode``/``head_units``/``head_max`` set the head
    turn's action head. Driving (``scenario='driving'``): ``action_mode`` 'discrete' or 'continuous' sets the actor
    heads; the head settings do not apply."""

    # Set by each scenario's build, None where they do not apply (declared here for mypy; no class attributes).
    action_mode: str | None
    head_mode: str | None
    head_max: float | None
    pose_head: nn.Linear | None
    reconstruction: ReconstructionHead | None
    command_centre: torch.Tensor              # driving, continuous: buffers
    command_half_range: torch.Tensor

    def __init__(self, feature_size: int = 64, head_mode: str = "discrete", head_units: int = 3,
                 head_max: float = math.radians(37.5), scenario: str = "soccer",
                 action_mode: str = "discrete", uses_pose: bool = False) -> None:
        super().__init__()
        if scenario not in SCENARIOS:
            raise ValueError(f"scenario must be one of {SCENARIOS}, got {scenario!r}")
        if not isinstance(uses_pose, bool):
            raise ValueError(f"uses_pose must be True or False, got {uses_pose!r}")
        self.scenario = scenario
        self.uses_pose = uses_pose
        _NETWORKS[scenario].build(self, feature_size, head_mode, head_units, head_max, action_mode, uses_pose)

    def _build_soccer(self, feature_size: int, head_mode: str, head_units: int, head_max: float, action_mode: str,
                      uses_pose: bool) -> None:
        """The soccer network's layers (``action_mode`` is driving's)."""
        self.action_mode = None
        if head_mode not in ("discrete", "continuous"):
            raise ValueError(f"head_mode must be 'discrete' or 'continuous', got {head_mode!r}")
        D = feature_size
        self.feature_size, self.head_mode, self.head_max = D, head_mode, head_max
        self.self_state_size = PROPRIOCEPTION + (POSE_INPUT if uses_pose else 0)
        self.localization = Stream(D, ACTION_ENCODING + self.self_state_size)
        self.pose_head = nn.Linear(D, POSE_SIZE)
        self.objects = Stream(D, POSE_SIZE + self.self_state_size)
        self.walk_head = nn.Linear(2 * D, 5)
        self.turn_head = nn.Linear(2 * D, 3)
        self.kick_head = nn.Linear(2 * D, 3)
        if head_mode == "discrete":
            self.head_head = nn.Linear(2 * D, 2 * head_units + 1)
        else:
            self.head_head = nn.Linear(2 * D, 1)
            self.head_log_std = nn.Parameter(torch.full((1,), math.log(0.3 * head_max)))
        self.critic = nn.Sequential(nn.Linear(2 * D, D), nn.LeakyReLU(0.1), nn.LayerNorm(D), nn.Linear(D, 1))
        self.reconstruction = ReconstructionHead(D)

    def _build_driving(self, feature_size: int, head_mode: str, head_units: int, head_max: float, action_mode: str,
                       uses_pose: bool) -> None:
        """The driving network's layers (the head settings are soccer's; a pose input is refused)."""
        if uses_pose:
            raise ValueError("uses_pose: the pose estimate is a soccer input; a driving agent has none")
        action_mode = driving_actions.check_action_mode(action_mode)
        inputs = agent_inputs("driving")
        D = feature_size
        self.feature_size, self.action_mode = D, action_mode
        self.head_mode, self.head_max = None, None
        self.self_state_size = inputs.self_state
        self.localization = Stream(D, inputs.action_encoding + inputs.self_state, inputs.num_classes, temporal=False)
        self.pose_head = None
        self.objects = Stream(D, inputs.self_state, inputs.num_classes, temporal=False)
        if action_mode == "discrete":
            self.acceleration_head = nn.Linear(2 * D, driving_actions.ACCELERATION_CHOICES)
            self.steering_head = nn.Linear(2 * D, driving_actions.STEERING_CHOICES)
        else:
            size = driving_actions.CONTINUOUS_SIZE
            self.command_head = nn.Linear(2 * D, size)
            self.command_log_std = nn.Parameter(torch.tensor(driving_actions.INITIAL_STD).log())
            low, high = torch.tensor(driving_actions.CONTINUOUS_LOW), torch.tensor(driving_actions.CONTINUOUS_HIGH)
            self.register_buffer("command_centre", (low + high) / 2, persistent=False)
            self.register_buffer("command_half_range", (high - low) / 2, persistent=False)
            with torch.no_grad():       # start near INITIAL_COMMAND (brake released): driving_actions says why
                start = (torch.tensor(driving_actions.INITIAL_COMMAND) - self.command_centre) / self.command_half_range
                self.command_head.bias.copy_(torch.atanh(start))
        self.critic = nn.Sequential(nn.Linear(2 * D, D), nn.LeakyReLU(0.1), nn.LayerNorm(D), nn.Linear(D, 1))
        self.reconstruction = None

    def initial_state(self, batch: int) -> State:
        zeros = torch.zeros(batch, self.feature_size, device=next(self.parameters()).device)
        return (zeros, zeros.clone(), zeros.clone(), zeros.clone())

    def forward(self, landmarks: StreamBatch, objects: StreamBatch, previous_action: torch.Tensor,
                proprioception: torch.Tensor, state: State) -> AgentStep:
        """One motion period of B robots: streams (B, F, N, ...), previous_action (B, 12), proprioception (B, 7) —
        the self state; (B, 14) with the pose estimate appended when ``uses_pose`` —, state four (B, D) tensors."""
        return self._periods(landmarks, objects, previous_action, proprioception, state, None)

    def forward_sequence(self, landmarks: StreamBatch, objects: StreamBatch, previous_action: torch.Tensor,
                         proprioception: torch.Tensor, state: State, resets: torch.Tensor | None = None
                         ) -> AgentSequence:
        """T consecutive motion periods of B robots (a rollout): streams (T, B, F, N, ...), previous_action
        (T, B, 12), proprioception (T, B, 7) (14 when ``uses_pose``), ``state`` the four (B, D) tensors before the
        first period, ``resets`` (T, B) bool, True = the robot's episode starts at that period (its recurrent state is zeroed before it;
        None: no resets). Gives what T calls of ``forward`` with the state carried (and zeroed at the resets) give,
        stacked; the embeddings and the RTA run over all T·B periods at once (they do not depend on earlier
        periods), only the two LSTM cells step through the periods."""
        T, B = previous_action.shape[:2]
        if resets is None:
            resets = torch.zeros(T, B, dtype=torch.bool, device=previous_action.device)
        if resets.shape != (T, B):
            raise ValueError(f"resets must have shape {(T, B)}, got {tuple(resets.shape)}")

        def flat(batch: StreamBatch) -> StreamBatch:
            return StreamBatch(batch.features.flatten(0, 1), batch.kind.flatten(0, 1), batch.mask.flatten(0, 1))

        step = self._periods(flat(landmarks), flat(objects), previous_action.flatten(0, 1),
                             proprioception.flatten(0, 1), state, resets)
        fields = {name: (value.unflatten(0, (T, B)) if isinstance(value, torch.Tensor) else value)
                  for name, value in vars(step).items() if name != "state"}
        return AgentSequence(**fields, state=step.state)

    def _periods(self, landmarks: StreamBatch, objects: StreamBatch, previous_action: torch.Tensor,
                 proprioception: torch.Tensor, state: State, resets: torch.Tensor | None) -> AgentStep:
        """T·B periods, period-major (T = 1 when resets is None), as one flat batch; the LSTMs step through T."""
        return _NETWORKS[self.scenario].periods(self, landmarks, objects, previous_action, proprioception, state,
                                                resets)

    def _soccer_periods(self, landmarks: StreamBatch, objects: StreamBatch, previous_action: torch.Tensor,
                        proprioception: torch.Tensor, state: State, resets: torch.Tensor | None) -> AgentStep:
        """``_periods`` of the soccer network: the pose between the streams, soccer's actor heads and the
        reconstruction."""
        if not _tracing() and proprioception.shape[-1] != self.self_state_size:
            raise ValueError(
                f"self state of width {proprioception.shape[-1]}, this agent takes {self.self_state_size}: "
                + ("it uses the pose estimate (uses_pose): side_inputs(batch, head_max, pose=True) with "
                   "'pose_estimate' in the batch" if self.uses_pose else
                   "it does not use the pose estimate (uses_pose False): side_inputs(..., pose=False)"))
        if self.uses_pose:
            proprioception = torch.cat([proprioception[:, :PROPRIOCEPTION],
                                        encode_pose(proprioception[:, PROPRIOCEPTION:])], dim=-1)
        loc_pooled, landmark_confidence = self.localization.encode(landmarks)
        obj_pooled, object_confidence = self.objects.encode(objects)
        loc_in = self.localization.transform(torch.cat([loc_pooled, previous_action, proprioception], dim=-1))
        loc_h, loc_state = self.localization.recur(loc_in, state[:2], resets)
        loc = self.localization.norm(loc_h)
        pose = cast(nn.Linear, self.pose_head)(loc)                     # (soccer's heads: set in this scenario)
        obj_in = self.objects.transform(torch.cat([obj_pooled, pose.detach(), proprioception], dim=-1))
        obj_h, obj_state = self.objects.recur(obj_in, state[2:], resets)
        obj = self.objects.norm(obj_h)
        phi = torch.cat([loc, obj], dim=-1)
        if self.head_mode == "discrete":
            head = self.head_head(phi)
        else:
            mean = cast(float, self.head_max) * torch.tanh(self.head_head(phi))
            head = torch.cat([mean, self.head_log_std.expand_as(mean)], dim=-1)
        ball, ball_conf, robots, robot_conf = cast(ReconstructionHead, self.reconstruction)(obj)
        return AgentStep(self.walk_head(phi), self.turn_head(phi), self.kick_head(phi), head,
                         self.critic(phi).squeeze(-1), pose, phi, obj, loc_state + obj_state,
                         landmark_confidence, object_confidence, ball, ball_conf, robots, robot_conf)

    def _driving_periods(self, static: StreamBatch, objects: StreamBatch, previous_action: torch.Tensor,
                         self_state: torch.Tensor, state: State, resets: torch.Tensor | None) -> AgentStep:
        """``_periods`` of the driving network: no pose between the streams, driving's actor heads."""
        loc_pooled, static_confidence = self.localization.encode(static)
        obj_pooled, object_confidence = self.objects.encode(objects)
        loc_in = self.localization.transform(torch.cat([loc_pooled, previous_action, self_state], dim=-1))
        loc_h, loc_state = self.localization.recur(loc_in, state[:2], resets)
        loc = self.localization.norm(loc_h)
        obj_in = self.objects.transform(torch.cat([obj_pooled, self_state], dim=-1))
        obj_h, obj_state = self.objects.recur(obj_in, state[2:], resets)
        obj = self.objects.norm(obj_h)
        phi = torch.cat([loc, obj], dim=-1)
        heads: dict[str, torch.Tensor] = {}
        if self.action_mode == "discrete":
            heads["acceleration"], heads["steering"] = self.acceleration_head(phi), self.steering_head(phi)
        else:
            mean = self.command_centre + self.command_half_range * torch.tanh(self.command_head(phi))
            heads["command"] = torch.cat([mean, self.command_log_std.expand_as(mean)], dim=-1)
        return AgentStep(None, None, None, None, self.critic(phi).squeeze(-1), None, phi, obj, loc_state + obj_state,
                         static_confidence, object_confidence, **heads)

    def distributions(self, step: AgentStep) -> list[Any]:
        """One distribution per action dimension: soccer's categorical walk, turn, kick and the head categorical or
        Gaussian; driving's (``driving_actions.distributions``) two categorical heads or three clipped Gaussians."""
        return _NETWORKS[self.scenario].distributions(self, step)

    def _soccer_distributions(self, step: AgentStep) -> list[Any]:
        heads: list[Categorical | Normal] = [Categorical(logits=step.walk), Categorical(logits=step.turn),
                                             Categorical(logits=step.kick)]
        if self.head_mode == "discrete":
            heads.append(Categorical(logits=step.head))
        else:
            head = cast(torch.Tensor, step.head)
            heads.append(Normal(head[..., 0], head[..., 1].exp()))
        return heads

    def _driving_distributions(self, step: AgentStep) -> list[Any]:
        return driving_actions.distributions(cast(str, self.action_mode), step.acceleration, step.steering,
                                             step.command)

    def act(self, step: AgentStep, generator: torch.Generator | None = None, greedy: bool = False
            ) -> torch.Tensor:
        """(B, 4) actions [walk, turn, kick, head] — head an index (discrete) or rad per period (continuous,
        clipped to the head's limit). Driving: (B, 2) [acceleration, steering] indices, or (B, 3) the normalised
        command clipped to its bounds (``driving_actions``). Drawn by ``core.action_draws`` from each categorical's
        ``probs`` and each Gaussian's parameters. Samples carry no gradient (score-function estimators need them
        fixed)."""
        heads: list[torch.Tensor | Gaussian] = []
        for dist in self.distributions(step):
            if isinstance(dist, driving_actions.ClippedNormal):
                heads.append(Gaussian(dist.loc, dist.scale, dist.low, dist.high))
            elif isinstance(dist, Categorical):
                heads.append(dist.probs)
            else:
                limit = cast(float, self.head_max)
                heads.append(Gaussian(dist.mean, dist.stddev, -limit, limit))
        drawn = draw_actions(heads, generator, greedy)
        columns = [c if isinstance(head, Gaussian) else c.float() for head, c in zip(heads, drawn)]
        return torch.stack(columns, dim=-1).detach()


@dataclass(frozen=True)
class ScenarioNetwork:
    """What differs between the scenarios' networks (module docstring): the ``DynEnvAgent`` methods that build its
    layers, run its periods and turn a step's outputs into distributions."""
    build: Callable[[DynEnvAgent, int, str, int, float, str, bool], None]
    periods: Callable[[DynEnvAgent, StreamBatch, StreamBatch, torch.Tensor, torch.Tensor, State,
                       torch.Tensor | None], AgentStep]
    distributions: Callable[[DynEnvAgent, AgentStep], list[Any]]


# Each scenario's network, by its name (the registry, dynenv_ros.scenarios, sits above this layer).
_NETWORKS = {"soccer": ScenarioNetwork(DynEnvAgent._build_soccer, DynEnvAgent._soccer_periods,
                                       DynEnvAgent._soccer_distributions),
             "driving": ScenarioNetwork(DynEnvAgent._build_driving, DynEnvAgent._driving_periods,
                                        DynEnvAgent._driving_distributions)}


def parameter_count(model: nn.Module) -> int:
    return sum(p.numel() for p in model.parameters())
