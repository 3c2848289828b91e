"""Acting on a period by a deadline (``decision_deadline``; docs/deploy.md, "A real camera's timing"): when a
robot's period is due on the node's clock, and the frames that stand in for the ones that never came. ROS-free:
messages are read by attribute, times are integer nanoseconds.

- **The frame interval** is learnt from the frames themselves (``FrameInterval``: the median of Δstamp / Δslot
  between a robot's consecutive frames, slot = period · F + index), so no rate parameter can disagree with the
  camera's.
- **Due** (``due_ns``): a frame that arrives at node time a with index k says the period's last frame is due at
  a + (F − 1 − k) · interval. The earliest over the period's frames is kept, so a late frame never pushes the
  deadline out; measuring from arrival rather than comparing stamps with the clock keeps it right when the
  camera's clock and the node's differ (an unsynchronised camera, wall-clock nodes beside sim stamps).
- **A missing frame** (``fill``) is the nearest frame received before it (else after it) with no detections, its
  own index, and the stamp its slot has: what the network sees when the camera saw nothing, with the robot's own
  state carried over. The network has no per-frame validity input (agent/inputs.py masks detections, not frames),
  and the emulated vision pipeline never drops a frame — it only misses detections, down to none — so an empty
  frame is the one representation a trained policy knows; the node counts the missing frames
  (``frames_missing``) and the periods they are in (``periods_partial``).
"""
from __future__ import annotations

import statistics
from collections import deque
from collections.abc import Callable, Mapping
from typing import Any

INTERVAL_SAMPLES = 15        # the median of this many recent Δstamp / Δslot estimates
AUTO_DEADLINE = -2.0         # decision_deadline's default: a deadline on the wall clock, none on sim time
WALL_CLOCK_DEADLINE = 0.05   # s: below a 10 Hz camera's interval, so a lost last frame is answered in its period
MAX_SLOT_GAP = 64            # consecutive frames further apart say nothing reliable about the interval


def stamp_ns(msg: Any) -> int:
    stamp = msg.header.stamp
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


def slot_of(msg: Any) -> int:
    """A frame's place in the robot's sequence of frames: period · frames_per_period + index."""
    return int(msg.motion_period) * int(msg.frames_per_period) + int(msg.frame_index)


class FrameInterval:
    """The camera's frame interval (ns) from the frames' stamps and slots (module docstring)."""

    def __init__(self, samples: int = INTERVAL_SAMPLES) -> None:
        self.previous: dict[str, tuple[int, int]] = {}      # robot -> (slot, stamp) of its newest frame
        self.estimates: deque[float] = deque(maxlen=samples)

    def observe(self, robot: str, msg: Any) -> None:
        slot, stamp = slot_of(msg), stamp_ns(msg)
        before = self.previous.get(robot)
        if before is not None and 0 < slot - before[0] <= MAX_SLOT_GAP and stamp > before[1]:
            self.estimates.append((stamp - before[1]) / (slot - before[0]))
        if before is None or slot > before[0] or slot < before[0] - MAX_SLOT_GAP:
            self.previous[robot] = (slot, stamp)

    @property
    def ns(self) -> int | None:
        """The interval, None before two consecutive frames of one robot arrived."""
        return round(statistics.median(self.estimates)) if self.estimates else None


def resolve_deadline(value: float, use_sim_time: bool) -> float:
    """The deadline a node acts by (s; negative: none). ``AUTO_DEADLINE`` is safe by default: on a robot (the wall
    clock) a camera that drops a period's last frame must not stop the robot, so 0.05 s; on sim time a stepped game
    delivers complete periods and a deadline on a clock that waits for the node could only cut them, so none."""
    if value == AUTO_DEADLINE:
        return -1.0 if use_sim_time else WALL_CLOCK_DEADLINE
    return value


def due_ns(arrival_ns: int, frame_index: int, frames_per_period: int, interval_ns: int) -> int:
    """When, on the node's clock, the period's last frame is due, judged from one frame's arrival."""
    return arrival_ns + (frames_per_period - 1 - frame_index) * interval_ns


def fill(frames: Mapping[int, Any], frames_per_period: int, interval_ns: int | None,
         empty: Callable[[Any, int, int], Any]) -> tuple[list[Any], int]:
    """The period in frame order, each missing frame ``empty(like, index, stamp_ns)`` after the nearest received
    frame ``like`` (before it, else after it) and stamped where its slot is; and how many were missing."""
    if not frames:
        raise ValueError("a period needs at least one received frame to be filled")
    received = sorted(frames)
    period, missing = [], 0
    for k in range(frames_per_period):
        if k in frames:
            period.append(frames[k])
            continue
        before = [j for j in received if j < k]
        j = before[-1] if before else received[0]
        like = frames[j]
        stamp = stamp_ns(like) + (k - j) * (interval_ns or 0)
        period.append(empty(like, k, max(stamp, 0)))
        missing += 1
    return period, missing


__all__ = ["AUTO_DEADLINE", "WALL_CLOCK_DEADLINE", "FrameInterval", "due_ns", "fill", "resolve_deadline", "slot_of",
           "stamp_ns"]
