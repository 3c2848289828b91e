"""Observations → the network's inputs: padded tensors and masks per stream, batched over robots.

The one observation layout is ``dynenv_ros.envs.padded_layout`` (what ``robocup_v0(observation="padded")`` and the
vectorised batch return, and what the policy node builds from DetectionArray messages): ``streams_from_padded``
turns it into the two streams of the paper's encoder — landmarks (for localization) and dynamic objects (ball,
robots) — with tensor operations only, and ``side_inputs`` into the self-state and previous-action vectors.
``collate`` packs variable-length detection rows into that layout first. Padding is explicit (``mask`` True =
padded slot), so no detection, frame or batch entry ever needs special-casing downstream.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping, Sequence

import numpy as np
import torch

from dynenv_ros.envs.padded_layout import (FEATURES, GAME_COLUMNS, LANDMARK_CLASSES, OBJECT_CLASSES,
                                           PROPRIOCEPTION_COLUMNS, PaddedLayout, pack_frames)

DYNAMIC_CLASSES = OBJECT_CLASSES
# Embedding index of each class (one MLP per class); 0 is reserved for padding and unknown classes.
CLASS_INDEX = {int(c): i + 1 for i, c in enumerate(DYNAMIC_CLASSES + LANDMARK_CLASSES)}
NUM_CLASSES = len(CLASS_INDEX) + 1
_KIND = torch.zeros(256, dtype=torch.int64)
for _cls, _index in CLASS_INDEX.items():
    _KIND[_cls] = _index
# The GameController's values reach the network scaled to about unit size: ownership relation as is, its seconds
# over a free kick's length, the game's seconds over a 10-minute half.
GAME_SCALE = torch.tensor([1.0, 1 / 10.0, 1 / 600.0])


@dataclass
class StreamBatch:
    """One stream's detections: ``features`` (B, F, N, FEATURES), ``kind`` (B, F, N) class embedding index,
    ``mask`` (B, F, N) True where padded."""
    features: torch.Tensor
    kind: torch.Tensor
    mask: torch.Tensor


def _as_tensor(value) -> torch.Tensor:
    return value if isinstance(value, torch.Tensor) else torch.from_numpy(np.asarray(value, np.float32))


def stream(features, valid) -> StreamBatch:
    """One stream from padded rows (B, F, N, FEATURES) and a validity mask (B, F, N), 1 = a detection."""
    features, valid = _as_tensor(features), _as_tensor(valid)
    kind = _KIND[features[..., 0].long().clamp(0, 255)]
    padded = valid < 0.5
    return StreamBatch(features, kind.masked_fill(padded, 0), padded)


def streams_from_padded(observation: Mapping[str, object]) -> tuple[StreamBatch, StreamBatch]:
    """(landmarks, dynamic objects) of a batch of padded observations (keys of ``PaddedLayout``, robots leading)."""
    return (stream(observation["landmarks"], observation["landmark_mask"]),
            stream(observation["objects"], observation["object_mask"]))


def side_inputs(observation: Mapping[str, object], head_max: float) -> tuple[torch.Tensor, torch.Tensor]:
    """(previous action encoding (B, ACTION_ENCODING), self state (B, SELF_STATE)) of padded observations: the
    period's last proprioception row and the GameController's values, scaled."""
    action = _as_tensor(observation["previous_action"])
    previous = encode_previous_action(action[:, 0], action[:, 1], action[:, 2], action[:, 3], head_max)
    return previous, self_state(_as_tensor(observation["proprioception"])[:, -1], observation["game"])


def self_state(proprioception, game) -> torch.Tensor:
    """(B, SELF_STATE): the last frame's proprioception (B, 4) and the GameController's values (B, 3), scaled."""
    return torch.cat([_as_tensor(proprioception), _as_tensor(game) * GAME_SCALE], dim=-1)


def collate(observations: Sequence[Sequence[np.ndarray]], max_landmarks: int | None = None,
            max_objects: int | None = None) -> tuple[StreamBatch, StreamBatch]:
    """(landmarks, dynamic objects) for a batch of robots; each observation is a sequence of frames, each frame a
    (k, FEATURES) float array of detection rows nearest first (``robocup_v0``'s ``obs["detections"]``). Packed
    into the padded layout — with the batch's own maxima where none are given; beyond a fixed maximum the
    farthest rows are dropped, as everywhere."""
    frames = [[np.asarray(rows, np.float32).reshape(-1, FEATURES) for rows in entry] for entry in observations]
    arrays, _ = pack_frames(PaddedLayout.fitting(frames, max_landmarks, max_objects), frames)
    return streams_from_padded(arrays)


def encode_previous_action(walk: torch.Tensor, turn: torch.Tensor, kick: torch.Tensor, head: torch.Tensor,
                           head_max: float) -> torch.Tensor:
    """(B, 12): one-hot walk (5), turn (3), kick (3) and the head turn scaled to [-1, 1] — every dimension kept
    (DynEnv folded both side steps into one value and dropped the kick, facts §12.16)."""
    return torch.cat([torch.nn.functional.one_hot(walk.long(), 5).float(),
                      torch.nn.functional.one_hot(turn.long(), 3).float(),
                      torch.nn.functional.one_hot(kick.long(), 3).float(),
                      (head.float() / head_max).unsqueeze(-1)], dim=-1)


ACTION_ENCODING = 12
PROPRIOCEPTION = len(PROPRIOCEPTION_COLUMNS) + len(GAME_COLUMNS)      # the network's self-state input
