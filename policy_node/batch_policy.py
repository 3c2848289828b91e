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

import time
from collections import Counter
from collections.abc import Callable, Sequence
from typing import Any, Protocol

import numpy as np
import torch

from dynenv_ros.agent.inputs import streams_from_padded
from dynenv_ros.envs.detection_messages import pack_messages
from dynenv_ros.envs.pose_features import POSE_KEY
from dynenv_ros.envs.pose_messages import PoseHistory, pose_batch, stamp_ns
from dynenv_ros.scenarios import DRIVING, SOCCER, Scenario
from dynenv_ros.scenarios.soccer import HEAD_BOUND, uses_pose

DEFAULT_FRAMES = SOCCER.default_frames      # the trial's frame count before any frame arrived
STAND_STILL = SOCCER.idle          # the fallback action of a robot whose decision failed or was not finite
BRAKE = DRIVING.idle               # driving's: [throttle, brake, steering] (also the previous action at reset)
POSE_WAIT_S = 0.02                 # the longest a decision waits for its frame's pose estimate (wall clock)
POSE_POLL_S = 0.001


class Log(Protocol):
    """The node's logger, as the core calls it (rclpy's takes ``throttle_duration_sec``)."""

    def error(self, message: str, **options: Any) -> Any: ...

    def info(self, message: str, **options: Any) -> Any: ...


def decision_seed(seed: int, episode: int, period: int) -> int:
    """A sampling seed per (node seed, episode, period): which periods a slow node drops, or whether it answers
    an episode's last period, cannot change the draws of any other decision, so stepped runs stay reproducible."""
    return int(np.random.SeedSequence([seed, episode, period]).generate_state(1, np.uint64)[0] >> 1)


def one_line(error: BaseException) -> str:
    text = str(error).strip()
    return text.splitlines()[0] if text else type(error).__name__


class BatchPolicy:
    """The acting policy (``policy``, swapped between decisions) and how a batch of periods is put to it (module
    docstring), in ``scenario`` with the game's ``settings`` (``Scenario.game_settings``). ``memories`` are the
    robots' ``decider.RobotMemory`` in ``names`` order; ``take_estimates`` files the pose estimates already waiting
    before their rows are read."""

    def __init__(self, names: Sequence[str], *, scenario: Scenario, settings: Any, seed: int,
                 greedy: bool, pose_max_age: float, counts: Counter[str], log: Log,
                 take_estimates: Callable[[], None], empty_period: Callable[[int], list[Any]]) -> None:
        self.names, self.scenario, self.settings = list(names), scenario, settings
        self.spec = scenario.layout_spec(settings)
        self.idle = scenario.idle
        self.seed, self.greedy, self.counts, self.log = seed, greedy, counts, log
        self.teams = {name: 1 if name.startswith("team_a") else -1 for name in self.names}   # robocup's team signs
        self.pose_histories = {name: PoseHistory() for name in self.names}
        self.pose_max_age = pose_max_age
        self.take_estimates, self.empty_period = take_estimates, empty_period
        self.policy: Any = None            # set by the node once its first policy passed ``check``
        self.pose_wanted = False
        self.dropped_detections = 0          # rows beyond the maxima, farthest first
        self.trial_note = ""                 # what the last ``check`` ran its trial decision on
        self._choices: Any = None

    def refresh_pose(self) -> bool:
        """Whether the acting policy takes the pose estimate (driving never does)."""
        self.pose_wanted = self.scenario.takes_pose(self.policy)
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
            previous, proprio = self.scenario.side_inputs(observation, self.policy, self.spec, self.pose_wanted)
            states = [m.state or self.policy.initial_state(1) for m in memories]
            state = tuple(torch.cat([s[i] for s in states]) for i in range(4))
            step = self.policy(landmarks, objects, previous, proprio, state)
            actions, finite, self._choices = self.scenario.choose(step, self.policy, generator, self.greedy,
                                                                  self.settings)
        except Exception as error:
            self.counts["failed_decisions"] += 1
            self.log.error(f"decision failed, robots {self.scenario.idle_words}: "
                           f"{type(error).__name__}: {one_line(error)}", throttle_duration_sec=5.0)
            return np.zeros((len(memories), len(self.idle))), np.zeros(len(memories), bool), None
        if not finite.all():
            self.log.error(f"non-finite outputs for {[n for n, f in zip(self.names, finite) if not f]}: "
                           "they stand still", throttle_duration_sec=5.0)
        return actions, finite, step

    def behaviour(self, step: Any, actions: np.ndarray, finite: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Each robot's action log-probability and value estimate, for the trainer (NaN where unknown: the
        fallback action was not the policy's choice, and the learning fields stay 0)."""
        n = len(actions)
        if step is None or not finite.any():
            return np.full(n, np.nan), np.full(n, np.nan)
        log_probs = self.scenario.log_probs(step, self.policy, actions, self._choices)
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
        pose_used, pose_missing, pose_stale). Takes every estimate already waiting first, and waits for one still
        on its way (``_await_estimates``)."""
        stamps = [stamp_ns(p[-1].header.stamp) for p in periods]
        self.take_estimates()
        self._await_estimates(periods, stamps)
        return pose_batch([self.pose_histories[n] for n in self.names], stamps, [self.teams[n] for n in self.names],
                          round(self.pose_max_age * 1e9), self.counts)

    def _behind(self, periods: list[list[Any]], stamps: Sequence[int]) -> bool:
        """Some robot's estimator is alive (its newest estimate at most ``pose_max_age`` before the frame) but has
        not yet delivered the estimates of its period's last frame: one stamped at or after it, or as many stamped
        at it as the period has frames with that stamp (the simulator's first period repeats one instant in every
        frame, one estimate each)."""
        max_age = round(self.pose_max_age * 1e9)
        for name, period, stamp in zip(self.names, periods, stamps):
            entries = self.pose_histories[name].entries
            if not entries or stamp - entries[-1][0] > max_age or entries[-1][0] > stamp:
                continue
            needed = sum(stamp_ns(frame.header.stamp) == stamp for frame in period)
            if sum(entry[0] == stamp for entry in entries) < needed:
                return True
        return False

    def _await_estimates(self, periods: list[list[Any]], stamps: Sequence[int]) -> None:
        """The simulator sends each frame's estimate before its detections, but on another topic, so a loaded
        machine can deliver the frame first; the decision would then take the frame before's estimate, and a
        stepped game would depend on delivery order. So while ``_behind``, take what arrives, for at most
        ``POSE_WAIT_S`` of wall time (a real stack's localization, stamped on its own clock, costs at most that);
        a wait that ends without the estimate is counted (``pose_late``). No wait where no estimator is alive."""
        if not self._behind(periods, stamps):
            return
        give_up = time.monotonic() + POSE_WAIT_S
        while True:
            time.sleep(POSE_POLL_S)
            self.take_estimates()
            if not self._behind(periods, stamps):
                return
            if time.monotonic() >= give_up:
                self.counts["pose_late"] += 1
                return

    def check(self, policy: Any, memories: Sequence[Any], graph_frames: int | None) -> None:
        """The scenario's ``check_policy`` on the last frames each robot acted on (a synthetic period with no
        detections where there are none yet), with the frame count the graph sends once known; ValueError with the
        reason."""
        try:
            self.scenario.check_kind(policy, self.settings)
            self.scenario.check_policy(policy, self._trial_inputs(policy, memories, graph_frames), graph_frames,
                                       self.settings)
        except ValueError as error:
            raise ValueError(f"policy refused: {one_line(error)}") from None

    def _trial_inputs(self, policy: Any, memories: Sequence[Any], graph_frames: int | None):
        frames = graph_frames or getattr(policy, "frames", None) or self.scenario.default_frames
        periods = [m.last if m.last is not None and len(m.last) == frames else self.empty_period(frames)
                   for m in memories]
        recorded = sum(m.last is not None and len(m.last) == frames for m in memories)
        self.trial_note = (f"the last frames of {recorded} robot{'s' * (recorded != 1)}" if recorded
                           else f"an empty period of {frames} frames (no frames received yet)")
        observation, _ = pack_messages(periods, [m.previous for m in memories],
                                       getattr(policy, "max_landmarks", None), getattr(policy, "max_objects", None),
                                       spec=self.spec)
        return self.scenario.trial_inputs(observation, policy, self.spec)


__all__ = ["BRAKE", "DEFAULT_FRAMES", "HEAD_BOUND", "STAND_STILL", "BatchPolicy", "Log", "decision_seed",
           "one_line", "uses_pose"]
