"""One camera frame from the messages a team's stack publishes per class (issue 41; docs/deploy.md, "The ros-sports
route"). ROS-free: messages are opaque, stamps and arrival times integer nanoseconds.

ros-sports vision stacks publish one ``soccer_vision_3d_msgs`` array per class and frame (balls, robots, goalposts,
markings), each on its own topic with its own header. The frame they describe is found by stamp: parts whose stamps
lie within ``tolerance_ns`` of a frame's first part belong to it. A frame goes on (to the frame grid and the
policy) when

- every expected kind has arrived (complete), or
- every kind still missing has already delivered a part of a newer frame (that stream has moved on: the part was
  lost), or
- ``wait_ns`` has passed since its first part arrived (the caller's clock: ``due``), whatever came —

so a stack that drops one class's message, or never publishes a class, delays a frame by at most ``wait_ns``. A
missing kind is a class with no detections in that frame, which is also how the emulation reports a class it did
not see. Refused and counted: a second part of a kind for a frame that has one (``parts_duplicate``; the first is
kept), a part of a frame already passed on (``parts_late``). Bounded: at most ``max_open`` frames wait at once; a
part that would open another closes the oldest first.
"""
from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field
from typing import Any


@dataclass
class Frame:
    """A frame's parts so far: kind → message; ``stamp_ns`` of its first part; ``first_arrival_ns``."""
    stamp_ns: int
    first_arrival_ns: int
    parts: dict[str, Any] = field(default_factory=dict)


class FrameParts:
    """One camera's per-class messages grouped into frames (module docstring)."""

    def __init__(self, kinds: tuple[str, ...], tolerance_ns: int, wait_ns: int, max_open: int = 8,
                 counts: Counter[str] | None = None) -> None:
        if not kinds:
            raise ValueError("a frame needs at least one kind of message")
        if tolerance_ns <= 0 or wait_ns < 0 or max_open < 1:
            raise ValueError(f"tolerance must be positive, wait non-negative and max_open ≥ 1, got "
                             f"{tolerance_ns}, {wait_ns}, {max_open}")
        self.kinds = tuple(kinds)
        self.tolerance_ns = tolerance_ns
        self.wait_ns = wait_ns
        self.max_open = max_open
        self.open: list[Frame] = []                 # oldest stamp first
        self.newest_by_kind: dict[str, int] = {}    # kind -> the newest stamp it delivered
        self.passed_ns: int | None = None           # the newest stamp passed on
        self.counts: Counter[str] = Counter() if counts is None else counts

    def add(self, kind: str, stamp_ns: int, arrival_ns: int, message: Any) -> list[Frame]:
        """File one part; the frames it completes or closes, oldest first."""
        if kind not in self.kinds:
            raise ValueError(f"unexpected kind '{kind}'; this camera's kinds are {self.kinds}")
        if self.passed_ns is not None and stamp_ns <= self.passed_ns + self.tolerance_ns and not any(
                abs(f.stamp_ns - stamp_ns) <= self.tolerance_ns for f in self.open):
            self.counts["parts_late"] += 1
            return []
        frame = next((f for f in self.open if abs(f.stamp_ns - stamp_ns) <= self.tolerance_ns), None)
        out: list[Frame] = []
        if frame is None:
            if len(self.open) >= self.max_open:
                out.append(self._pass(self.open[0]))
            frame = Frame(stamp_ns, arrival_ns)
            self.open.append(frame)
            self.open.sort(key=lambda f: f.stamp_ns)
        if kind in frame.parts:
            self.counts["parts_duplicate"] += 1
            return out
        frame.parts[kind] = message
        self.newest_by_kind[kind] = max(stamp_ns, self.newest_by_kind.get(kind, stamp_ns))
        for f in list(self.open):
            if self._finished(f):
                out.append(self._pass(f))
        return out

    def due(self, now_ns: int) -> list[Frame]:
        """The frames whose wait is over at ``now_ns``, oldest first (with whatever parts came)."""
        return [self._pass(f) for f in list(self.open) if now_ns - f.first_arrival_ns >= self.wait_ns]

    def _finished(self, frame: Frame) -> bool:
        missing = [k for k in self.kinds if k not in frame.parts]
        return all(self.newest_by_kind.get(k, -1) > frame.stamp_ns + self.tolerance_ns for k in missing)

    def _pass(self, frame: Frame) -> Frame:
        self.open.remove(frame)
        self.passed_ns = frame.stamp_ns if self.passed_ns is None else max(self.passed_ns, frame.stamp_ns)
        if len(frame.parts) < len(self.kinds):
            self.counts["frames_incomplete"] += 1
            self.counts["parts_missing"] += len(self.kinds) - len(frame.parts)
        return frame


__all__ = ["Frame", "FrameParts"]
