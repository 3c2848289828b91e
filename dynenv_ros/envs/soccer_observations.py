"""What a soccer agent observes each motion period, in one of three modes:

- ``partial`` (default): each vision frame's detections from the perception model (``perception/``), as float32
  rows (``perception.detections.FEATURE_COLUMNS``), plus proprioception per frame;
- ``full``: the noise-free ground truth in the robot's team frame (``soccer_spaces.GroundTruthEncoder``);
- ``image``: per frame, semantic segmentation of the NAO's top and bottom cameras (``perception/camera.py``),
  rendered from the frame's (noisy) detections, plus proprioception.

Partial and image modes also give the observation reward (what was truly seen); full mode gives none, as in DynEnv.
"""
from __future__ import annotations

from typing import Any, Mapping

import numpy as np
from gymnasium import spaces

from dynenv_ros.core.arrays import clamp
from dynenv_ros.envs.soccer_spaces import GroundTruthEncoder
from dynenv_ros.perception.detections import FEATURE_COLUMNS, as_features
from dynenv_ros.perception.params import PerceptionParams, load_preset
from dynenv_ros.soccer.config import SoccerConfig
from dynenv_ros.soccer.vision import SoccerVision
from dynenv_ros.soccer.world import SoccerWorld

OBSERVATION_MODES = ("partial", "full", "image")
PROPRIOCEPTION_COLUMNS = ("head_yaw", "fallen", "penalized", "kicking")
FEATURE_BOUND = 50.0


def perception_params(setting: str | Mapping[str, Any] | PerceptionParams) -> PerceptionParams:
    """A preset name, a mapping {"preset": name, **overrides}, or ready parameters."""
    if isinstance(setting, PerceptionParams):
        return setting
    if isinstance(setting, str):
        return load_preset(setting)
    if isinstance(setting, Mapping):
        values = dict(setting)
        return load_preset(values.pop("preset", "realistic"), **values)
    raise ValueError(f"perception must be a preset name or a mapping, got {setting!r}")


class SoccerObservations:
    """Builds every agent's observation for one period; hook ``on_frame`` into ``SoccerWorld.step``."""

    def __init__(self, config: SoccerConfig, mode: str = "partial",
                 perception: str | Mapping[str, Any] | PerceptionParams = "realistic",
                 image_size: tuple[int, int] = (640, 480)) -> None:
        if mode not in OBSERVATION_MODES:
            raise ValueError(f"observation must be one of {OBSERVATION_MODES}, got {mode!r}")
        self.config = config
        self.mode = mode
        self.frames = config.rates.frames_per_period
        self.params = perception_params(perception)
        self.ground_truth = GroundTruthEncoder(config)
        self.vision: SoccerVision | None = None
        self._frame = 0
        proprio_space = spaces.Box(-np.pi, np.pi, (self.frames, len(PROPRIOCEPTION_COLUMNS)), np.float32)
        if mode == "full":
            self.space: spaces.Space = self.ground_truth.observation_space
        elif mode == "partial":
            row = spaces.Box(-FEATURE_BOUND, FEATURE_BOUND, (len(FEATURE_COLUMNS),), np.float32)
            self.space = spaces.Dict({"detections": spaces.Tuple([spaces.Sequence(row, stack=True)] * self.frames),
                                      "proprioception": proprio_space})
        else:
            from dynenv_ros.perception.camera import CHANNELS_PER_CAMERA, ImageConfig
            self.image_config = ImageConfig(*image_size)
            shape = (self.frames, 2 * CHANNELS_PER_CAMERA, self.image_config.height, self.image_config.width)
            self.space = spaces.Dict({"images": spaces.Box(0, 1, shape, np.uint8),
                                      "proprioception": proprio_space})

    def reset(self, world: SoccerWorld) -> None:
        self.world = world
        if self.mode != "full":
            if self.vision is None:
                self.vision = SoccerVision(world, self.params)
            else:
                self.vision.world = world
                self.vision.reset()
        self._frame = 0

    def on_frame(self, index: int) -> None:
        if self.mode == "full":
            return
        self.vision.frame(index)

    def initial(self) -> list[Any]:
        """Observations after reset: every frame of the period shows the initial state."""
        if self.mode != "full":
            for k in range(self.frames):
                self.on_frame(k)
        return self.build()[0]

    def build(self) -> tuple[list[Any], np.ndarray]:
        """(one observation per robot, observation reward per robot) for the frames recorded this period."""
        n = self.config.n_robots
        if self.mode == "full":
            rows = self.ground_truth.observations(self.world)
            return [rows[i] for i in range(n)], np.zeros(n)
        perception = self.vision.perceive()
        rewards = self.vision.observation_rewards(perception)
        proprio = self.vision.proprioception                                # (F, n, 4)
        frames = len(perception) // n
        if self.mode == "partial":
            features = clamp(as_features(perception.detections), -FEATURE_BOUND, FEATURE_BOUND)
            off = perception.offsets
            out = [{"detections": tuple(features[off[k * n + i]:off[k * n + i + 1]] for k in range(frames)),
                    "proprioception": proprio[:, i]} for i in range(n)]
            return out, rewards
        from dynenv_ros.perception.camera import render_segmentation
        out = []
        for i in range(n):
            images = np.stack([render_segmentation(perception.of_view(k * n + i), self.image_config)
                               for k in range(frames)])
            out.append({"images": images, "proprioception": proprio[:, i]})
        return out, rewards
