"""What perception looks at: the world's objects at one or more vision instants, and who is looking.

Scenario-independent: soccer fills it from its world (``soccer/vision.py``), driving will too. Point objects have
a class, a nominal size, an absolute team and per-frame poses; lines are static segments; a circle is optional.
A circle (soccer's centre circle) is a point object of class CENTER_CIRCLE whose size is its diameter.
A *view* is one observer at one frame; perception handles all views of a motion period in one vectorised pass.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class SceneObjects:
    """The point objects of a scenario, fixed for an episode (poses come per frame)."""
    class_id: np.ndarray      # (N,) uint8 ObjectClass
    object_id: np.ndarray     # (N,) int32, the world's id (robots: robot id)
    size_x: np.ndarray        # (N,) m
    size_y: np.ndarray        # (N,) m
    team: np.ndarray          # (N,) int8 absolute team (+1 / -1 / 0)
    subtype: np.ndarray       # (N,) uint8
    occluder: np.ndarray      # (N,) bool: can hide what is behind it (robots)
    dynamic: np.ndarray       # (N,) bool: moves (ball, robots) — only these make neighbours NEARBY
    lines: np.ndarray         # (L, 4) static segments [x1, y1, x2, y2] in the world frame

    def __post_init__(self) -> None:
        n = len(self.class_id)
        for name in ("object_id", "size_x", "size_y", "team", "subtype", "occluder", "dynamic"):
            if len(getattr(self, name)) != n:
                raise ValueError(f"SceneObjects.{name} has {len(getattr(self, name))} entries, expected {n}")
        if self.lines.ndim != 2 or self.lines.shape[1] != 4:
            raise ValueError(f"SceneObjects.lines must be (L, 4), got {self.lines.shape}")


@dataclass
class SceneFrames:
    """Poses and states of every object at F vision instants (world frame)."""
    x: np.ndarray             # (F, N)
    y: np.ndarray             # (F, N)
    yaw: np.ndarray           # (F, N), NaN where undefined
    fallen: np.ndarray        # (F, N) bool
    penalized: np.ndarray     # (F, N) bool


@dataclass
class Views:
    """Who looks when: V views, each an observer (object index) at a frame, with its head yaw."""
    frame: np.ndarray         # (V,) int
    observer: np.ndarray      # (V,) int, index into the scene's objects
    head_yaw: np.ndarray      # (V,) rad, relative to the observer's body

    def __len__(self) -> int:
        return len(self.frame)
