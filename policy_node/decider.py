"""The policy node's decisions without ROS: each controlled robot's frames filed into motion periods
(``periods.py``, and ``partial_periods.py`` with a decision deadline), one batch decision once every robot has a
period ready (``batch_policy.BatchPolicy``), and each robot's action addressed to the next period that has not
started. Messages are read by attribute; the node (``policy_node.py``) takes them off ROS, logs the refusals this
returns and publishes the actions it hands over.

- **Filing** (``store``): a malformed frame is refused with the reason (counted, ``frames_malformed``); a frame of
  a new episode starts its robot afresh; with a deadline an incomplete period's due time is kept
  (``partial_periods.due_ns``) and ``close_overdue`` fills the gaps of one that is overdue.
- **Ready** (``decide``): every robot has a period ready, of the same episode and frame count. A robot still holding
  the previous episode's last period while another has the new episode's first drops it and waits (that answer
  would be ignored, and deciding both together would leave the new episode waiting: a stepped game stalls).
- **Addressed**: frames that arrived while deciding (the node's ``take_waiting``) say which periods have started
  since; an action addressed to one of them would be refused as late, so it goes to the next period that has not
  started (``actions_delayed``); the first action per period wins (``actions_superseded``).
"""
from __future__ import annotations

import statistics
import time
from collections import Counter
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

from dynenv_ros.envs.detection_messages import frame_problem
from policy_node.batch_policy import STAND_STILL, BatchPolicy, Log
from policy_node.partial_periods import FrameInterval, due_ns, fill
from policy_node.periods import PeriodMemory, close_period, file_frame, period_problem


class RobotMemory(PeriodMemory):
    """What the node keeps per robot between periods: its frames (``periods.PeriodMemory``) and more."""

    def __init__(self, idle: tuple = STAND_STILL) -> None:
        super().__init__()
        self.idle = idle
        self.addressed: int | None = None              # the period its last action was sent for
        self.last: list[Any] | None = None             # its frames (the trial decision of a new policy)
        self.state: tuple | None = None
        self.previous = idle                           # soccer: [walk, turn, kick, head]; driving: the command


class CannotPlay(Exception):
    """The policy takes ``fixed`` vision frames per period and the graph sends ``frames``: the node must stop."""

    def __init__(self, fixed: int, frames: int) -> None:
        super().__init__(fixed, frames)
        self.fixed, self.frames = fixed, frames


@dataclass(frozen=True)
class Outgoing:
    """One robot's action of a decision: ``frame`` is the last frame of the period acted on, ``target`` the
    period the action is for; ``learning`` (log-probability, value) when the action is the policy's own."""
    name: str
    frame: Any
    target: int
    action: tuple
    learning: tuple[float, float] | None


class Decider:
    """Frames in, decisions out, for the robots ``names`` (module docstring). ``deadline_ns``: act on a period's
    frames that arrived this long after its last one was due (None: complete periods only); ``now_ns``: the node's
    clock; ``empty_like(like, index, stamp_ns)``: a frame that never came (``partial_periods.fill``)."""

    def __init__(self, names: Sequence[str], batch: BatchPolicy, counts: Counter[str], log: Log,
                 deadline_ns: int | None, now_ns: Callable[[], int],
                 empty_like: Callable[[Any, int, int], Any]) -> None:
        self.names, self.batch, self.counts, self.log = list(names), batch, counts, log
        self.deadline_ns, self.now_ns, self.empty_like = deadline_ns, now_ns, empty_like
        self.memory = {name: RobotMemory(batch.idle) for name in self.names}
        self.frame_interval = FrameInterval()       # learnt from the stamps (partial_periods)
        self.graph_frames: int | None = None        # frames per period of the detections arriving
        self.latencies_ms: list[float] = []
        self.window_latencies: list[float] = []     # since the last diagnostics

    def memories(self) -> list[RobotMemory]:
        return [self.memory[n] for n in self.names]

    def check(self, policy: Any) -> None:
        """A new policy's trial decision on the robots' last frames (``BatchPolicy.check``); ValueError if refused."""
        self.batch.check(policy, self.memories(), self.graph_frames)

    def swap(self, policy: Any) -> None:
        """The recurrent states carry over when they fit the new network; a network of another size starts from
        fresh states. The caller swaps between two decisions."""
        if policy.feature_size != self.batch.policy.feature_size:
            for memory in self.memory.values():
                memory.state = None
        self.batch.policy = policy

    # -- frames ----------------------------------------------------------------------------------------------------
    def store(self, name: str, msg: Any) -> str:
        """File one frame (``periods.file_frame``); a new episode resets the robot. With a decision deadline, an
        incomplete period's due time is kept (``partial_periods.due_ns``: the earliest its frames say). Returns why
        the frame was refused ('' if filed)."""
        self.counts["frames_received"] += 1
        memory = self.memory[name]
        problem = frame_problem(msg) or period_problem(memory, msg)
        if problem:
            self.counts["frames_malformed"] += 1
            return problem
        if memory.episode != msg.episode_id:                 # a new episode: forget everything
            memory.__init__(self.batch.idle)
            memory.episode = msg.episode_id
        if self.deadline_ns is None:
            file_frame(memory, msg, self.counts)
            return ""
        self.frame_interval.observe(name, msg)
        interval = self.frame_interval.ns
        if file_frame(memory, msg, self.counts, self._close) and interval is not None:
            due = due_ns(self.now_ns(), msg.frame_index, msg.frames_per_period, interval)
            memory.due = due if memory.due is None else min(memory.due, due)
        return ""

    def _close(self, frames: dict[int, Any]) -> list[Any]:
        """An incomplete period with its gaps filled by empty frames (``partial_periods.fill``), counted."""
        period, missing = fill(frames, next(iter(frames.values())).frames_per_period, self.frame_interval.ns,
                               self.empty_like)
        self.counts["frames_missing"] += missing
        return period

    def close_overdue(self) -> None:
        """Close every robot's period whose deadline passed (gaps filled)."""
        now = self.now_ns()
        for memory in self.memory.values():
            if memory.frames and memory.due is not None and now >= memory.due + self.deadline_ns:
                close_period(memory, self.counts, self._close)

    # -- decisions -------------------------------------------------------------------------------------------------
    def decide(self, take_waiting: Callable[[], None], send: Callable[[Outgoing], None]) -> bool:
        """Decide if every robot has a complete period, handing each action to ``send``; True if it did (the
        frames ``take_waiting`` filed after the decision may have made the next one ready: nothing else would
        wake the node for frames already taken). CannotPlay when the policy cannot play the graph's periods."""
        memories = self.memories()
        periods = self._ready(memories)
        if periods is None:
            return False
        started = time.perf_counter()
        actions, finite, step = self.batch.run(memories, periods)
        log_probs, values = self.batch.behaviour(step, actions, finite)
        for memory, period in zip(memories, periods):          # consumed: newer frames are no longer stale-checked
            memory.decided, memory.ready = period[-1].motion_period, None
        take_waiting()             # which periods started while deciding
        for b, (name, memory, period) in enumerate(zip(self.names, memories, periods)):
            frame = period[-1]
            same_episode = memory.episode == frame.episode_id
            started_since = max(frame.motion_period, memory.period) if same_episode else frame.motion_period
            action = tuple(actions[b]) if finite[b] else self.batch.idle
            target = started_since + 1
            if same_episode and memory.addressed is not None and target <= memory.addressed:
                # the previous, slower decision already answered that period (first action per period wins):
                # this one only advances the recurrent state
                self.counts["actions_superseded"] += 1
            else:
                if started_since > frame.motion_period:
                    self.counts["actions_delayed"] += 1
                send(Outgoing(name, frame, target, action,
                              (float(log_probs[b]), float(values[b])) if finite[b] else None))
                if same_episode:
                    memory.addressed = target
                    memory.previous = self.batch.scenario.previous_action(action)
            if same_episode:                                   # (a new episode's first frames reset the robot)
                memory.state = tuple(s[b:b + 1] for s in step.state) if finite[b] else None
                memory.last = period
            if not finite[b]:
                self.counts["fallback_actions"] += 1
        self.counts["decisions"] += 1
        self._measured(1000 * (time.perf_counter() - started))
        return True

    def _ready(self, memories: list[RobotMemory]) -> list[list[Any]] | None:
        """Every robot's ready period, if each has one of the newest episode and all have one frame count; stale
        or mismatched ones are dropped (counted). CannotPlay for a policy of another fixed frame count."""
        if any(m.ready is None for m in memories):
            return None
        newest = max(m.ready[0].episode_id for m in memories)
        stale = [m for m in memories if m.ready[0].episode_id != newest]
        if stale:
            for m in stale:
                m.ready = None
            self.counts["periods_dropped"] += len(stale)
            return None
        periods = [m.ready for m in memories]
        frames = len(periods[0])
        if any(len(p) != frames for p in periods):
            self.log.error(f"robots' periods have different frame counts {[len(p) for p in periods]}: "
                           "dropped", throttle_duration_sec=5.0)
            for m in memories:
                m.ready = None
            self.counts["periods_dropped"] += len(memories)
            return None
        self.graph_frames = frames
        fixed = getattr(self.batch.policy, "frames", None)
        if fixed is not None and fixed != frames:
            raise CannotPlay(fixed, frames)
        return periods

    def _measured(self, latency: float) -> None:
        self.latencies_ms.append(latency)
        self.window_latencies.append(latency)
        if len(self.latencies_ms) % 100 == 0:
            recent = self.latencies_ms[-100:]
            self.latencies_ms = self.latencies_ms[-100:]
            self.log.info(f"decision latency for {len(self.names)} robots: median "
                          f"{statistics.median(recent):.2f} ms, max {max(recent):.2f} ms")


__all__ = ["CannotPlay", "Decider", "Outgoing", "RobotMemory"]
