"""The policy acting for every robot a policy node controls, one batch per decision: ROS-free (the frames and pose
estimates are read by attribute), so the decider (``policy_node/decider.py``) and its node share one definition of
what the network is given and what is done with its outputs.

- **The batch** (``padded``): each robot's period packed into the scenario's padded layout
  (``envs.detection_messages.pack_messages``, the layout the trainer learns from), with its previous action; a
  policy that takes the pose estimate gets each robot's newest estimate at or before its period's last frame
  (``pose_rows``: ``envs.pose_messages.pose_batch``, in the robot's team's frame; none or a stale one is "lost").
- **The decision** (``run``): one forward pass for the batch with every robot's recurrent state; actions sampled
  from a generator seeded per (node seed, episode, period) (``decision_seed``), or the most likely ones
  (``greedy``); a policy that raises gives every robot the fallback (counted, logged).
- **What the trainer learns from** (``behaviour``): each action's log-probability and value estimate.
- **A new policy's trial** (``check``): ``agent.export.check_policy`` (or ``check_driving_policy``) on the last
  frames each robot acted on, or an empty period before any frame came.
"""
from __future__ import annotations

import math
from collections import Counter
from collections.abc import Callable, Sequence
from typing import Any, Protocol

import numpy as np
import torch

from dynenv_ros.agent import driving_actions
from dynenv_ros.agent.export import (behaviour_log_probs, check_driving_policy, check_policy, check_scenario,
                                     sample_actions)
from dynenv_ros.agent.inputs import side_inputs, streams_from_padded
from dynenv_ros.driving.config import DrivingConfig
from dynenv_ros.envs.detection_messages import pack_messages
from dynenv_ros.envs.driving_observations import driving_layout_spec
from dynenv_ros.envs.padded_layout import SOCCER
from dynenv_ros.envs.pose_features import POSE_KEY
from dynenv_ros.envs.pose_messages import LOST_ROW, PoseHistory, pose_batch, stamp_ns
from dynenv_ros.soccer.config import MotionConfig, SoccerConfig

# The simulator refuses a head turn beyond this per period (docs/ros_graph.md): a policy must stay inside it.
HEAD_BOUND = MotionConfig().head_max_delta
DEFAULT_FRAMES = SoccerConfig().rates.frames_per_period      # the trial's frame count before any frame arrived
STAND_STILL = (0, 0, 0, 0.0)       # the fallback action of a robot whose decision failed or was not finite
BRAKE = driving_actions.BRAKE_COMMAND  # driving's: [throttle, brake, steering] (also the previous action at reset)


class Log(Protocol):
    """The node's logger, as the core calls it (rclpy's takes ``throttle_duration_sec``)."""

    def error(self, message: str, **options: Any) -> Any: ...

    def info(self, message: str, **options: Any) -> Any: ...


def uses_pose(policy: Any) -> bool:
    """Whether a policy takes the ``pose_estimate`` input: its torch model's ``uses_pose`` (absent, so False, in
    older checkpoints), or an ONNX file's input of that name."""
    own = getattr(policy, "uses_pose", None)        # TorchPolicy / OnnxPolicy say it themselves
    if isinstance(own, bool):
        return own
    model = getattr(policy, "model", None)
    if model is not None:
        return bool(getattr(model, "uses_pose", False))
    session = getattr(policy, "session", None)
    if session is not None:
        return any(i.name == POSE_KEY for i in session.get_inputs())
    return False


def decision_seed(seed: int, episode: int, period: int) -> int:
    """A sampling seed per (node seed, episode, period): which periods a slow node drops, or whether it answers
    an episode's last period, cannot change the draws of any other decision, so stepped runs stay reproducible."""
    return int(np.random.SeedSequence([seed, episode, period]).generate_state(1, np.uint64)[0] >> 1)


def one_line(error: BaseException) -> str:
    text = str(error).strip()
    return text.splitlines()[0] if text else type(error).__name__


class BatchPolicy:
    """The acting policy (``policy``, swapped between decisions) and how a batch of periods is put to it (module
    docstring). ``memories`` are the robots' ``decider.RobotMemory`` in ``names`` order; ``take_estimates`` files
    the pose estimates already waiting before their rows are read."""

    def __init__(self, names: Sequence[str], *, driving: bool, action_mode: str, n_cars: int, seed: int,
                 greedy: bool, pose_max_age: float, counts: Counter[str], log: Log,
                 take_estimates: Callable[[], None], empty_period: Callable[[int], list[Any]]) -> None:
        self.names, self.driving, self.action_mode = list(names), driving, action_mode
        driving_config = DrivingConfig(n_cars=n_cars, action_mode=action_mode)
        self.spec = driving_layout_spec(driving_config) if driving else SOCCER
        self.max_yaw_rate = driving_config.cars.max_yaw_rate
        self.idle = BRAKE if driving else STAND_STILL
        self.seed, self.greedy, self.counts, self.log = seed, greedy, counts, log
        self.teams = {name: 1 if name.startswith("team_a") else -1 for name in self.names}   # robocup's team signs
        self.pose_histories = {name: PoseHistory() for name in self.names}
        self.pose_max_age = pose_max_age
        self.take_estimates, self.empty_period = take_estimates, empty_period
        self.policy: Any = None            # set by the node once its first policy passed ``check``
        self.pose_wanted = False
        self.dropped_detections = 0          # rows beyond the maxima, farthest first
        self.trial_note = ""                 # what the last ``check`` ran its trial decision on
        self._network_actions: Any = None

    def refresh_pose(self) -> bool:
        """Whether the acting policy takes the pose estimate (driving never does)."""
        self.pose_wanted = not self.driving and uses_pose(self.policy)
        return self.pose_wanted

    def run(self, memories: Sequence[Any], periods: list[list[Any]]):
        """(actions (B, 4), finite (B,), step) of one decision — driving: (B, 3) commands [throttle, brake,
        steering], the network's own actions (indices or normalised values) kept in ``self._network_actions`` for
        their log-probabilities; a policy that raises gives every robot the fallback (counted, logged): one bad
        decision must not stop the node or a stepped game."""
        first = periods[0][-1]
        generator = torch.Generator().manual_seed(decision_seed(self.seed, first.episode_id, first.motion_period))
        try:
            observation = self.padded(memories, periods)
            landmarks, objects = streams_from_padded(observation, self.spec)
            if self.driving:
                previous, proprio = side_inputs(observation, spec=self.spec)
            else:
                head_max = float(self.policy.head_max)
                previous, proprio = self._side_inputs(observation, head_max, self.pose_wanted)
            states = [m.state or self.policy.initial_state(1) for m in memories]
            state = tuple(torch.cat([s[i] for s in states]) for i in range(4))
            step = self.policy(landmarks, objects, previous, proprio, state)
            if self.driving:
                chosen, finite = driving_actions.sample_actions(step, self.policy.action_mode, generator, self.greedy)
                self._network_actions = chosen
                actions = driving_actions.commands(chosen, self.policy.action_mode, self.max_yaw_rate)
            else:
                actions, finite = sample_actions(step, self.policy.head_mode, self.policy.head_units, head_max,
                                                 generator, self.greedy)
        except Exception as error:
            self.counts["failed_decisions"] += 1
            self.log.error(f"decision failed, robots {'brake' if self.driving else 'stand still'}: "
                           f"{type(error).__name__}: {one_line(error)}", throttle_duration_sec=5.0)
            return np.zeros((len(memories), len(self.idle))), np.zeros(len(memories), bool), None
        if not finite.all():
            self.log.error(f"non-finite outputs for {[n for n, f in zip(self.names, finite) if not f]}: "
                           "they stand still", throttle_duration_sec=5.0)
        return actions, finite, step

    @staticmethod
    def _side_inputs(observation: dict[str, np.ndarray], head_max: float, pose: bool):
        """Soccer's side inputs; a policy taking the pose gets the batch's ``pose_estimate`` appended
        (``agent.inputs.side_inputs(..., pose=True)``)."""
        return side_inputs(observation, head_max, pose=True) if pose else side_inputs(observation, head_max)

    def behaviour(self, step: Any, actions: np.ndarray, finite: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Each robot's action log-probability and value estimate, for the trainer (NaN where unknown: the
        fallback action was not the policy's choice, and the learning fields stay 0)."""
        n = len(actions)
        if step is None or not finite.any():
            return np.full(n, np.nan), np.full(n, np.nan)
        if self.driving:
            log_probs = driving_actions.log_probs(step, self._network_actions, self.policy.action_mode)
        else:
            log_probs = behaviour_log_probs(step, actions, self.policy.head_mode, self.policy.head_units,
                                            float(self.policy.head_max))
        values = np.asarray(torch.as_tensor(step.value), np.float64).reshape(n)
        ok = finite & np.isfinite(log_probs) & np.isfinite(values)
        finite &= ok
        return log_probs, values

    def padded(self, memories: Sequence[Any], periods: list[list[Any]]) -> dict[str, np.ndarray]:
        stats: Counter[str] = Counter()
        observation, dropped = pack_messages(periods, [m.previous for m in memories],
                                             getattr(self.policy, "max_landmarks", None),
                                             getattr(self.policy, "max_objects", None), stats, self.spec)
        self.dropped_detections += dropped
        self.counts.update(stats)
        if self.pose_wanted:           # the network reads it from the batch (envs/pose_features.py)
            observation[POSE_KEY] = self.pose_rows(periods)
        return observation

    def pose_rows(self, periods: list[list[Any]]) -> np.ndarray:
        """(B, 7) float32 ``pose_estimate`` of the robots (``self.names`` order) for their periods: each robot's
        newest estimate at or before its period's last frame, in its team's frame; ``LOST_ROW`` (zeros, the
        standard deviations at the bound) without one, or when it is older than ``pose_max_age`` (counted:
        pose_used, pose_missing, pose_stale). Takes every estimate already waiting first."""
        self.take_estimates()
        return pose_batch([self.pose_histories[n] for n in self.names],
                          [stamp_ns(p[-1].header.stamp) for p in periods], [self.teams[n] for n in self.names],
                          round(self.pose_max_age * 1e9), self.counts)

    def check(self, policy: Any, scenario: str, memories: Sequence[Any], graph_frames: int | None) -> None:
        """``check_policy`` on the last frames each robot acted on (a synthetic period with no detections where
        there are none yet), with the frame count the graph sends once known; ValueError with the reason."""
        try:
            check_scenario(policy, scenario, self.action_mode if self.driving else None)
            if self.driving:
                check_driving_policy(policy, self._trial_inputs(policy, memories, graph_frames), self.max_yaw_rate,
                                     graph_frames)
            else:
                check_policy(policy, self._trial_inputs(policy, memories, graph_frames), HEAD_BOUND, graph_frames)
        except ValueError as error:
            raise ValueError(f"policy refused: {one_line(error)}") from None

    def _trial_inputs(self, policy: Any, memories: Sequence[Any], graph_frames: int | None):
        frames = graph_frames or getattr(policy, "frames", None) or (1 if self.driving else DEFAULT_FRAMES)
        periods = [m.last if m.last is not None and len(m.last) == frames else self.empty_period(frames)
                   for m in memories]
        recorded = sum(m.last is not None and len(m.last) == frames for m in memories)
        self.trial_note = (f"the last frames of {recorded} robot{'s' * (recorded != 1)}" if recorded
                           else f"an empty period of {frames} frames (no frames received yet)")
        observation, _ = pack_messages(periods, [m.previous for m in memories],
                                       getattr(policy, "max_landmarks", None), getattr(policy, "max_objects", None),
                                       spec=self.spec)
        if self.driving:
            return (*streams_from_padded(observation, self.spec), *side_inputs(observation, spec=self.spec))
        head_max = float(policy.head_max)
        if not math.isfinite(head_max) or head_max <= 0:
            head_max = 1.0            # check_policy refuses it with the reason; the trial inputs must stay finite
        if uses_pose(policy):         # the trial runs as a robot that has lost its pose
            observation[POSE_KEY] = np.tile(LOST_ROW, (len(periods), 1))
        return (*streams_from_padded(observation), *self._side_inputs(observation, head_max, uses_pose(policy)))


__all__ = ["BRAKE", "DEFAULT_FRAMES", "HEAD_BOUND", "STAND_STILL", "BatchPolicy", "Log", "decision_seed",
           "one_line", "uses_pose"]
