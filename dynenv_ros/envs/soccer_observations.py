"""What a soccer agent observes each motion period, in one of four modes:

- ``partial`` (default): each vision frame's detections from the perception model (``perception/``), as float32
  rows (``perception.detections.FEATURE_COLUMNS``, nearest first), plus proprioception per frame and the
  GameController's broadcast (``game``); variable length (gymnasium ``Sequence`` spaces);
- ``padded``: the same detections in the fixed-shape layout of ``envs.padded_layout`` (Box spaces every RL
  library can batch), with the previous action;
- ``full``: the noise-free ground truth in the robot's team frame (``soccer_spaces.GroundTruthEncoder``);
- ``image``: per frame, semantic segmentation of the NAO's top and bottom cameras (``perception/camera.py``),
  rendered from the frame's (noisy) detections, plus proprioception and ``game``. Declared as an image
  (uint8 0/255, channels first) so image-aware tools (e.g. Stable-Baselines3's CNN policies) treat it as one:
  channel ``8·frame + 4·camera + class`` with camera 0 top, 1 bottom and class 0 ball, 1 robot, 2 goalpost,
  3 lines (field lines, penalty marks, crossings, centre circle).

Partial, padded and image modes also give the observation reward (what was truly seen); full mode gives none, as
in DynEnv.

``localization="estimate"`` (partial, padded and image modes): the emulated self-localization runs
(``perception/localization.py``) and every observation gains ``pose_estimate``, (7,) float32, the robot's pose
estimate at the period's last frame in its team frame (``envs.pose_features``: columns, units, bounds).
``"none"`` (the default, the paper's configuration): nothing changes. ``True`` / ``False``: the estimate runs (or
not) without being observed (``self.vision.estimate``; what the scripted perceiving team reads). Full mode is
ground truth without perception, so it refuses ``"estimate"``.
"""
from __future__ import annotations

from typing import Any, Mapping

import numpy as np
from gymnasium import spaces

from dynenv_ros.envs.padded_layout import (ACTION_COLUMNS, FEATURE_BOUND, GAME_COLUMNS, PROPRIOCEPTION_COLUMNS,
                                           PaddedLayout)
from dynenv_ros.envs.learning_targets import LearningTargets
from dynenv_ros.envs.padded_layout import pose_space
from dynenv_ros.envs.pose_features import POSE_KEY, pose_features
from dynenv_ros.envs.soccer_spaces import GroundTruthEncoder
from dynenv_ros.perception.detections import FEATURE_COLUMNS
from dynenv_ros.perception.params import PerceptionParams, load_preset, resolve_setting
from dynenv_ros.soccer.actions import SoccerAction
from dynenv_ros.soccer.config import SoccerConfig
from dynenv_ros.soccer.vision import SoccerVision
from dynenv_ros.soccer.world import SoccerWorld

OBSERVATION_MODES = ("partial", "padded", "full", "image")
LOCALIZATION_OPTIONS = ("none", "estimate")
__all__ = ["OBSERVATION_MODES", "LOCALIZATION_OPTIONS", "localization_option", "PROPRIOCEPTION_COLUMNS", "GAME_COLUMNS", "ACTION_COLUMNS", "FEATURE_BOUND",
           "SoccerObservations", "perception_params", "previous_actions"]


def previous_actions(actions: list[SoccerAction]) -> np.ndarray:
    """(robots, 4) float32 [walk, turn, kick, head_yaw_delta rad] of the last period's commands."""
    return np.array([(int(a.walk), int(a.turn), int(a.kick), a.head_yaw_delta) for a in actions], np.float32)


def perception_params(setting: str | Mapping[str, Any] | PerceptionParams) -> PerceptionParams:
    """A preset name, a mapping {"preset": name, **overrides}, or ready parameters."""
    return resolve_setting(setting, PerceptionParams, load_preset, "a preset name or a mapping")


def localization_option(value: bool | str) -> tuple[bool, bool]:
    """(run the self-localization, observe its estimate) of a ``localization`` setting: ``"none"``, ``"estimate"``,
    or a bool (run it, unobserved)."""
    if isinstance(value, bool):
        return value, False
    if value not in LOCALIZATION_OPTIONS:
        raise ValueError(f"localization must be one of {LOCALIZATION_OPTIONS} ('estimate': observe the pose "
                         f"estimate as 'pose_estimate'), got {value!r}")
    return value == "estimate", value == "estimate"


class SoccerObservations:
    """Builds every agent's observation for one period; hook ``on_frame`` into ``SoccerWorld.step``."""

    def __init__(self, config: SoccerConfig, mode: str = "partial",
                 perception: str | Mapping[str, Any] | PerceptionParams = "realistic",
                 image_size: tuple[int, int] = (640, 480), max_landmarks: int | None = None,
                 max_objects: int | None = None, localization: bool | str = False) -> None:
        if mode not in OBSERVATION_MODES:
            raise ValueError(f"observation must be one of {OBSERVATION_MODES}, got {mode!r}")
        localization, self.pose_observed = localization_option(localization)
        if self.pose_observed and mode == "full":
            raise ValueError("localization='estimate' needs a perceived observation (partial, padded or image); "
                             "'full' is the noise-free ground truth, which has no pose estimate")
        self.config = config
        self.mode = mode
        self.frames = config.rates.frames_per_period
        self.params = perception_params(perception)
        self.ground_truth = GroundTruthEncoder(config)
        self.vision: SoccerVision | None = None
        self.localization = localization       # step the self-pose estimates (self.vision.estimate ...)
        self._frame = 0
        self.layout = PaddedLayout.for_players(config.players_per_team, self.frames, max_landmarks, max_objects,
                                               pose=self.pose_observed)
        padded = self.layout.space(head_max=config.motion.head_max_delta)
        proprio_space, game_space = padded["proprioception"], padded["game"]
        pose = {POSE_KEY: pose_space()} if self.pose_observed else {}
        if mode == "full":
            self.space: spaces.Space = self.ground_truth.observation_space
        elif mode == "partial":
            row = spaces.Box(-FEATURE_BOUND, FEATURE_BOUND, (len(FEATURE_COLUMNS),), np.float32)
            self.space = spaces.Dict({"detections": spaces.Tuple([spaces.Sequence(row, stack=True)] * self.frames),
                                      "proprioception": proprio_space, "game": game_space, **pose})
        elif mode == "padded":
            self.space = padded
        else:
            from dynenv_ros.perception.camera import CHANNELS_PER_CAMERA, ImageConfig
            self.image_config = ImageConfig(*image_size)
            shape = (self.frames * 2 * CHANNELS_PER_CAMERA, self.image_config.height, self.image_config.width)
            self.space = spaces.Dict({"images": spaces.Box(0, 255, shape, np.uint8),
                                      "proprioception": proprio_space, "game": game_space, **pose})
        self.dropped_rows = np.zeros(config.n_robots, np.int64)   # padded: rows beyond the maxima, last period
        self._targets: LearningTargets | None = None              # made on the first build_padded(targets=...)
        self._views: dict[int, tuple[np.ndarray, np.ndarray]] = {}  # per frame count: each view's robot, frame
        self._teams = np.where(np.arange(config.n_robots) < config.players_per_team, 1.0, -1.0)   # A +1, B -1

    def reset(self, world: SoccerWorld) -> None:
        if world.config is not self.config and world.config != self.config:
            # the world's settings changed between episodes (SoccerWorld.reset(config=...): a curriculum's start or
            # episode length); the ground truth's clock follows them, the layout stays
            self.config = world.config
            self.ground_truth = GroundTruthEncoder(world.config)
        self.world = world
        if self.mode != "full":
            if self.vision is None:
                self.vision = SoccerVision(world, self.params, localization=self.localization)
                # The compiled feature rows (numba is imported with the perception, never on the ground-truth path).
                from dynenv_ros.perception.row_kernels import clamped_features
                self._clamped_features = clamped_features
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

    def build_padded(self, out: dict[str, np.ndarray] | None = None,
                     targets: dict[str, np.ndarray] | None = None) -> np.ndarray:
        """Padded mode without per-robot dicts: fill ``out`` (``layout.empty(n_robots)``, or new arrays kept in
        ``self.arrays``) and return the observation reward per robot. For vectorised batches. ``targets``
        (``learning_targets.empty_targets(players_per_team, n_robots)``): also filled, with the learning targets of
        the same instant."""
        if self.mode != "padded":
            raise RuntimeError("build_padded() needs observation='padded'")
        perception = self.vision.perceive()
        rewards = self.vision.observation_rewards(perception)
        self.arrays = self._pack(perception, out)
        if targets is not None:
            if self._targets is None:
                self._targets = LearningTargets(self.config.players_per_team)
            self._targets.fill(self.vision, perception, targets)
        return rewards

    def initial_padded(self, out: dict[str, np.ndarray] | None = None,
                       targets: dict[str, np.ndarray] | None = None) -> None:
        for k in range(self.frames):
            self.on_frame(k)
        self.build_padded(out, targets)

    def _pack(self, perception, out: dict[str, np.ndarray] | None = None) -> dict[str, np.ndarray]:
        """The period's perception, the robots' proprioception and the GameController's last word, packed."""
        n = self.config.n_robots
        frames = len(perception) // n
        arrays = self.layout.empty(n) if out is None else out
        if frames not in self._views:
            views = np.arange(frames * n)
            self._views[frames] = (views % n, views // n)
        features = self._clamped_features(perception.detections, FEATURE_BOUND)    # clamp_features(as_features(…))
        self.dropped_rows = self.layout.pack_rows(features, perception.offsets, *self._views[frames], arrays,
                                                  clear=out is not None).reshape(frames, n).sum(axis=0)
        arrays["proprioception"][:, :frames] = self.vision.proprioception.transpose(1, 0, 2)
        arrays["game"][:] = self.vision.game_controller[-1]
        arrays["previous_action"][:] = previous_actions(self.world.last_actions)
        if self.pose_observed:
            self.pose_rows(arrays[POSE_KEY])
        return arrays

    def pose_rows(self, out: np.ndarray | None = None) -> np.ndarray:
        """(robots, 7) ``pose_estimate`` rows of the period's last frame (``envs.pose_features``)."""
        return pose_features(self.vision.estimate, self.vision.covariance, self._teams, out=out)

    def build(self) -> tuple[list[Any], np.ndarray]:
        """(one observation per robot, observation reward per robot) for the frames recorded this period."""
        n = self.config.n_robots
        if self.mode == "full":
            rows = self.ground_truth.observations(self.world)
            return [rows[i] for i in range(n)], np.zeros(n)
        if self.mode == "padded":
            rewards = self.build_padded()
            return [{key: value[i] for key, value in self.arrays.items()} for i in range(n)], rewards
        perception = self.vision.perceive()
        rewards = self.vision.observation_rewards(perception)
        proprio = self.vision.proprioception                                # (F, n, 4)
        game = self.vision.game_controller[-1]                              # (n, 3) at the last frame
        frames = len(perception) // n
        if self.mode == "partial":
            features = self._clamped_features(perception.detections, FEATURE_BOUND)   # clamp_features(as_features(…))
            off = perception.offsets
            out = [{"detections": tuple(features[off[k * n + i]:off[k * n + i + 1]] for k in range(frames)),
                    "proprioception": proprio[:, i], "game": game[i]} for i in range(n)]
        else:
            from dynenv_ros.perception.camera import render_segmentation
            out = []
            for i in range(n):
                images = np.concatenate([render_segmentation(perception.of_view(k * n + i), self.image_config)
                                         for k in range(frames)]) * np.uint8(255)
                out.append({"images": images, "proprioception": proprio[:, i], "game": game[i]})
        if self.pose_observed:
            for entry, row in zip(out, self.pose_rows()):
                entry[POSE_KEY] = row
        return out, rewards
