"""Detection lists → padded tensors and masks, batched over (environment × robot, vision frame, detection).

The perception's feature rows (``dynenv_ros.perception.detections.FEATURE_COLUMNS``) are split into the two streams
of the paper's encoder: landmarks (for localization) and dynamic objects (ball, robots). Padding is explicit
(``mask`` True = padded slot), so no detection, no frame and no batch entry ever needs special-casing downstream.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np
import torch

from dynenv_ros.core.object_classes import ObjectClass
from dynenv_ros.perception.detections import FEATURE_COLUMNS

FEATURES = len(FEATURE_COLUMNS)
LANDMARK_CLASSES = (ObjectClass.GOALPOST, ObjectClass.PENALTY_CROSS, ObjectClass.LINE_CROSSING,
                    ObjectClass.FIELD_LINE, ObjectClass.CENTER_CIRCLE)
DYNAMIC_CLASSES = (ObjectClass.BALL, ObjectClass.ROBOT)
# Embedding index of each class (one MLP per class); 0 is reserved for padding and unknown classes.
CLASS_INDEX = {int(c): i + 1 for i, c in enumerate(DYNAMIC_CLASSES + LANDMARK_CLASSES)}
NUM_CLASSES = len(CLASS_INDEX) + 1


@dataclass
class StreamBatch:
    """One stream's detections: ``features`` (B, F, N, FEATURES), ``kind`` (B, F, N) class embedding index,
    ``mask`` (B, F, N) True where padded."""
    features: torch.Tensor
    kind: torch.Tensor
    mask: torch.Tensor


def _stream(frames_per_entry: Sequence[Sequence[np.ndarray]], classes: tuple, max_objects: int | None
            ) -> StreamBatch:
    B = len(frames_per_entry)
    F = max((len(frames) for frames in frames_per_entry), default=1)
    wanted = np.array([int(c) for c in classes])
    selected = [[rows[np.isin(rows[:, 0].astype(int), wanted)] if len(rows) else rows.reshape(0, FEATURES)
                 for rows in frames] for frames in frames_per_entry]
    longest = max((len(rows) for frames in selected for rows in frames), default=0)
    N = max(1, longest if max_objects is None else max_objects)
    features = np.zeros((B, F, N, FEATURES), np.float32)
    kind = np.zeros((B, F, N), np.int64)
    mask = np.ones((B, F, N), bool)
    lookup = np.zeros(256, np.int64)
    for cls, index in CLASS_INDEX.items():
        lookup[cls] = index
    for b, frames in enumerate(selected):
        for f, rows in enumerate(frames):
            rows = rows[:N]                  # beyond a fixed maximum (deployment), the first rows are kept
            k = len(rows)
            features[b, f, :k] = rows
            kind[b, f, :k] = lookup[rows[:, 0].astype(np.int64)]
            mask[b, f, :k] = False
    return StreamBatch(torch.from_numpy(features), torch.from_numpy(kind), torch.from_numpy(mask))


def collate(observations: Sequence[Sequence[np.ndarray]], max_landmarks: int | None = None,
            max_objects: int | None = None) -> tuple[StreamBatch, StreamBatch]:
    """(landmarks, dynamic objects) for a batch of robots; each observation is a sequence of frames, each frame a
    (k, FEATURES) float array of detection rows (what ``robocup_v0`` gives under ``obs["detections"]``)."""
    observations = [[np.asarray(rows, np.float32).reshape(-1, FEATURES) for rows in frames]
                    for frames in observations]
    return (_stream(observations, LANDMARK_CLASSES, max_landmarks),
            _stream(observations, DYNAMIC_CLASSES, max_objects))


def encode_previous_action(walk: torch.Tensor, turn: torch.Tensor, kick: torch.Tensor, head: torch.Tensor,
                           head_max: float) -> torch.Tensor:
    """(B, 12): one-hot walk (5), turn (3), kick (3) and the head turn scaled to [-1, 1] — every dimension kept
    (DynEnv folded both side steps into one value and dropped the kick, facts §12.16)."""
    return torch.cat([torch.nn.functional.one_hot(walk.long(), 5).float(),
                      torch.nn.functional.one_hot(turn.long(), 3).float(),
                      torch.nn.functional.one_hot(kick.long(), 3).float(),
                      (head.float() / head_max).unsqueeze(-1)], dim=-1)


ACTION_ENCODING = 12
PROPRIOCEPTION = 4
