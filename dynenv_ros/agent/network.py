"""The agent of the DynEnv paper (section 4, Figure 6), rebuilt: per-class embeddings, intratemporal self-attention
and Recurrent Temporal Attention over the vision frames of a motion period, confidence-weighted pooling, a
localization stream and an object stream with LSTMs across periods, one actor head per action dimension (the
continuous head turn included) and a critic.

The recurrent state is explicit (a tuple of four (B, D) tensors in and out) so that a policy node can keep one
per robot and an ONNX export can carry it as inputs and outputs.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import nn
from torch.distributions import Categorical, Normal

from dynenv_ros.agent.inputs import ACTION_ENCODING, FEATURES, NUM_CLASSES, PROPRIOCEPTION, StreamBatch

POSE_SIZE = 6            # [x, y, cos(θ+h), sin(θ+h), cos h, sin h] in the team frame
State = tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]


class EmbedBlock(nn.Module):
    """Linear → LeakyReLU → LayerNorm, twice (the paper's per-class embedding)."""

    def __init__(self, in_features: int, size: int, hidden: int = 32) -> None:
        super().__init__()
        self.net = nn.Sequential(nn.Linear(in_features, hidden, bias=False), nn.LeakyReLU(0.1), nn.LayerNorm(hidden),
                                 nn.Linear(hidden, size, bias=False), nn.LeakyReLU(0.1), nn.LayerNorm(size))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.net(x)


class ClassEmbedding(nn.Module):
    """One EmbedBlock per object class, all with the same output size; each row goes through its class's block."""

    def __init__(self, size: int, classes: int = NUM_CLASSES) -> None:
        super().__init__()
        self.blocks = nn.ModuleList(EmbedBlock(FEATURES, size) for _ in range(classes))

    def forward(self, features: torch.Tensor, kind: torch.Tensor) -> torch.Tensor:
        every = torch.stack([block(features) for block in self.blocks], dim=-2)      # (..., C, D)
        index = kind.unsqueeze(-1).unsqueeze(-1).expand(*kind.shape, 1, every.shape[-1])
        return every.gather(-2, index).squeeze(-2)


class RecurrentTemporalAttention(nn.Module):
    """Self-attention over the objects of each frame, then attention from each frame's objects to the running
    summary of the earlier frames (fed back, Figure 4), then confidence-weighted pooling.

    The summary has one slot per detection slot: summary_t = LayerNorm(A_t + attention(A_t, summary_{t−1})), A_t the
    frame's self-attended objects (zero on its padded slots). DynEnv had LayerNorm(attention(...)) without the A_t
    term; then every value the attention mixes descends from frame 0 and later frames only steer the weights, so
    the residual lets the newest detections themselves reach the output.

    Mask rule: a summary slot is valid once it has held a detection in ANY frame so far (padded_so_far =
    padded_so_far & padded_t, as DynEnv's M = M ∧ mask_t); only slots never filled yet are zeroed, excluded as keys
    and left out of the pooling. A slot that is empty in the current frame but was filled earlier keeps a summary
    (its query is zero, so it becomes the attention's read of the earlier summary). Why: the summary is the memory
    of the whole motion period; masking it by the current frame alone made the pooled output zero whenever the
    period's last frame was empty, whatever the earlier frames saw (the object stream, 2v2 under a random policy:
    12–15 % of periods have an empty last frame after a ball or robot was seen earlier in the period).

    Both attentions carry a learned bias key/value, so a frame without detections still has one key to attend to.
    Pooling: Σ c_i·x_i / (1 + Σ c_i), c_i = sigmoid(w·x_i). Dividing by the confidences (not by the count, as DynEnv
    did) makes the output independent of how many low-confidence detections are present; the +1 keeps an empty or
    all-doubtful frame at a small, finite output instead of dividing by zero.
    """

    def __init__(self, size: int) -> None:
        super().__init__()
        self.object_attention = nn.MultiheadAttention(size, 1, add_bias_kv=True, batch_first=True)
        self.temporal_attention = nn.MultiheadAttention(size, 1, add_bias_kv=True, batch_first=True)
        self.norm = nn.LayerNorm(size)
        self.confidence = nn.Linear(size, 1)

    def forward(self, x: torch.Tensor, mask: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """x (B, F, N, D), mask (B, F, N) True = padded → pooled (B, D), confidences (B, N) of the final summary's
        slots (0 on slots no frame of the period filled)."""
        B, F, N, D = x.shape
        flat = x.reshape(B * F, N, D)
        flat_mask = mask.reshape(B * F, N)
        attended = self.object_attention(flat, flat, flat, key_padding_mask=flat_mask, need_weights=False)[0]
        attended = attended.reshape(B, F, N, D).masked_fill(mask.unsqueeze(-1), 0.0)
        summary, padded_so_far = attended[:, 0], mask[:, 0]
        for t in range(1, F):
            query = attended[:, t]
            fed_back = self.temporal_attention(query, summary, summary, key_padding_mask=padded_so_far,
                                               need_weights=False)[0]
            padded_so_far = padded_so_far & mask[:, t]
            summary = self.norm(query + fed_back).masked_fill(padded_so_far.unsqueeze(-1), 0.0)
        confidence = torch.sigmoid(self.confidence(summary)).squeeze(-1).masked_fill(padded_so_far, 0.0)
        pooled = (confidence.unsqueeze(-1) * summary).sum(1) / (1.0 + confidence.sum(1, keepdim=True))
        return pooled, confidence


class Stream(nn.Module):
    """Embed → RTA → mix in side information → LSTM cell across motion periods → LayerNorm."""

    def __init__(self, size: int, side: int) -> None:
        super().__init__()
        self.embed = ClassEmbedding(size)
        self.rta = RecurrentTemporalAttention(size)
        self.transform = nn.Sequential(nn.Linear(size + side, size), nn.LeakyReLU(0.1), nn.LayerNorm(size))
        self.lstm = nn.LSTMCell(size, size)
        self.norm = nn.LayerNorm(size)

    def forward(self, batch: StreamBatch, side: torch.Tensor, state: tuple[torch.Tensor, torch.Tensor]
                ) -> tuple[torch.Tensor, tuple[torch.Tensor, torch.Tensor], torch.Tensor]:
        pooled, confidence = self.rta(self.embed(batch.features, batch.kind), batch.mask)
        h, c = self.lstm(self.transform(torch.cat([pooled, side], dim=-1)), state)
        return self.norm(h), (h, c), confidence


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
    walk: torch.Tensor                 # (B, 5) logits
    turn: torch.Tensor                 # (B, 3)
    kick: torch.Tensor                 # (B, 3)
    head: torch.Tensor                 # (B, 2·units+1) logits, or (B, 2) [mean, log_std] in rad per period
    value: torch.Tensor                # (B,)
    pose: torch.Tensor                 # (B, 6) localization estimate
    phi: torch.Tensor                  # (B, 2D) features for the curiosity heads
    object_features: torch.Tensor      # (B, D) for the reconstruction head
    state: State
    landmark_confidence: torch.Tensor  # (B, N_landmarks)
    object_confidence: torch.Tensor    # (B, N_objects)
    ball: torch.Tensor | None = None               # (B, 3) reconstruction [x, y, owner]
    ball_confidence: torch.Tensor | None = None    # (B,) logit
    robots: torch.Tensor | None = None             # (B, S, 6) reconstruction
    robot_confidence: torch.Tensor | None = None   # (B, S) logits


class DynEnvAgent(nn.Module):
    def __init__(self, feature_size: int = 64, head_mode: str = "discrete", head_units: int = 3,
                 head_max: float = math.radians(37.5)) -> None:
        super().__init__()
        if head_mode not in ("discrete", "continuous"):
            raise ValueError(f"head_mode must be 'discrete' or 'continuous', got {head_mode!r}")
        D = feature_size
        self.feature_size, self.head_mode, self.head_max = D, head_mode, head_max
        self.localization = Stream(D, ACTION_ENCODING + PROPRIOCEPTION)
        self.pose_head = nn.Linear(D, POSE_SIZE)
        self.objects = Stream(D, POSE_SIZE + PROPRIOCEPTION)
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

    def initial_state(self, batch: int) -> State:
        zeros = torch.zeros(batch, self.feature_size)
        return (zeros, zeros.clone(), zeros.clone(), zeros.clone())

    def forward(self, landmarks: StreamBatch, objects: StreamBatch, previous_action: torch.Tensor,
                proprioception: torch.Tensor, state: State) -> AgentStep:
        loc, loc_state, landmark_confidence = self.localization(
            landmarks, torch.cat([previous_action, proprioception], dim=-1), state[:2])
        pose = self.pose_head(loc)
        obj, obj_state, object_confidence = self.objects(
            objects, torch.cat([pose.detach(), proprioception], dim=-1), state[2:])
        phi = torch.cat([loc, obj], dim=-1)
        if self.head_mode == "discrete":
            head = self.head_head(phi)
        else:
            mean = self.head_max * torch.tanh(self.head_head(phi))
            head = torch.cat([mean, self.head_log_std.expand_as(mean)], dim=-1)
        ball, ball_conf, robots, robot_conf = self.reconstruction(obj)
        return AgentStep(self.walk_head(phi), self.turn_head(phi), self.kick_head(phi), head,
                         self.critic(phi).squeeze(-1), pose, phi, obj, loc_state + obj_state,
                         landmark_confidence, object_confidence, ball, ball_conf, robots, robot_conf)

    def distributions(self, step: AgentStep) -> list[torch.distributions.Distribution]:
        """One distribution per action dimension: categorical walk, turn, kick; head categorical or Gaussian."""
        heads = [Categorical(logits=step.walk), Categorical(logits=step.turn), Categorical(logits=step.kick)]
        if self.head_mode == "discrete":
            heads.append(Categorical(logits=step.head))
        else:
            heads.append(Normal(step.head[:, 0], step.head[:, 1].exp()))
        return heads

    def act(self, step: AgentStep, generator: torch.Generator | None = None, greedy: bool = False
            ) -> torch.Tensor:
        """(B, 4) actions [walk, turn, kick, head] — head an index (discrete) or rad per period (continuous,
        clipped to the head's limit). Samples carry no gradient (score-function estimators need them fixed)."""
        columns = []
        for dist in self.distributions(step):
            if isinstance(dist, Categorical):
                if greedy:
                    columns.append(dist.probs.argmax(-1).float())
                else:
                    columns.append(torch.multinomial(dist.probs, 1, generator=generator).squeeze(-1).float())
            else:
                noise = torch.randn(dist.mean.shape, generator=generator)
                sample = dist.mean if greedy else dist.mean + dist.stddev * noise
                columns.append(sample.clamp(-self.head_max, self.head_max))
        return torch.stack(columns, dim=-1).detach()


def parameter_count(model: nn.Module) -> int:
    return sum(p.numel() for p in model.parameters())
