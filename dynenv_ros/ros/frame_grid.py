"""Which frame of which motion period a camera frame is, from its stamp (the reverse vision adapter's numbering;
docs/deploy.md, "A real camera's timing"). ROS-free: stamps are integer nanoseconds.

The grid: slot n is due at ``epoch + n / hz`` and is frame ``n % frames_per_period`` of motion period
``n // frames_per_period``. A stamp goes to its nearest slot when it lies within ``tolerance`` frame intervals of
it; otherwise it is refused as ``out_of_tolerance``. Why not ``round(stamp · hz)``: a camera whose frames fall near
half an interval (any camera, since its phase is its own) landed on either slot at random, so ±6 ms of jitter made
duplicate frame numbers and gaps, and no period was ever complete.

- **Epoch.** Fixed (seconds; 0 is the plain ``round(stamp · hz)`` numbering), or — the default — the first stamp's
  phase: the slot nearest the first stamp is placed exactly on it. Numbering stays absolute (slot ≈ stamp · hz, so
  a restarted adapter numbers as before) and is centred on the camera's own timing.
- **Phase tracking.** Every accepted frame pulls the epoch by ``gain`` times its offset, so a camera whose clock runs
  a little fast or slow (29.97 Hz for 30) stays centred instead of drifting out of tolerance.
- **Per camera.** One grid per robot: two robots' cameras have phases of their own.
- **Refusals, counted in ``counts``:** a second frame for a slot already filled is a ``duplicate`` (the first was
  passed on already and is kept); a frame more than ``window`` slots behind the newest is ``too_old`` (its period
  was acted on long ago); one before slot 0 (a fixed epoch later than the camera's stamps) is ``before_epoch``
  (motion periods count from 0). ``restart_after`` refusals in a row mean the camera's timing changed (a restarted driver,
  a clock that jumped): the grid re-anchors on the stamp that made it so and forgets its slots (``grid_restarts``).
"""
from __future__ import annotations

from collections import Counter
from dataclasses import dataclass

ACCEPTED = "ok"
DUPLICATE = "duplicate"
TOO_OLD = "too_old"
OUT_OF_TOLERANCE = "out_of_tolerance"
BEFORE_EPOCH = "before_epoch"
COUNT_KEYS = {ACCEPTED: "frames_accepted", DUPLICATE: "frames_duplicate", TOO_OLD: "frames_too_old",
              OUT_OF_TOLERANCE: "frames_out_of_tolerance", BEFORE_EPOCH: "frames_before_epoch"}


@dataclass(frozen=True)
class Assignment:
    """Where a stamp went: ``status`` (``ACCEPTED`` or the refusal), the nearest ``slot`` and the stamp's signed
    ``offset`` from it in frame intervals."""
    status: str
    slot: int
    offset: float
    period: int
    index: int


class FrameGrid:
    """One camera's frames on the grid of slots (module docstring)."""

    def __init__(self, hz: float, frames_per_period: int, tolerance: float = 0.4, epoch_s: float | None = None,
                 gain: float = 0.05, window: int | None = None, restart_after: int | None = None,
                 counts: Counter[str] | None = None) -> None:
        if not hz > 0 or frames_per_period < 1:
            raise ValueError(f"hz must be positive and frames_per_period at least 1, got {hz}, {frames_per_period}")
        if not 0 < tolerance <= 0.5 or not 0 <= gain < 1:
            raise ValueError(f"tolerance must be in (0, 0.5] and gain in [0, 1), got {tolerance}, {gain}")
        self.hz = float(hz)
        self.interval_ns = 1e9 / self.hz
        self.frames_per_period = frames_per_period
        self.tolerance = tolerance
        self.gain = gain
        self.window = 2 * frames_per_period if window is None else window
        self.restart_after = max(3, 2 * frames_per_period) if restart_after is None else restart_after
        self.epoch_ns: float | None = None if epoch_s is None else float(epoch_s) * 1e9
        self.newest: int | None = None
        self.filled: set[int] = set()
        self.refused_in_a_row = 0
        self.counts: Counter[str] = Counter() if counts is None else counts

    def _anchor(self, stamp_ns: int) -> None:
        """Put the slot nearest ``stamp_ns`` exactly on it (the epoch is its phase)."""
        self.epoch_ns = stamp_ns - round(stamp_ns / self.interval_ns) * self.interval_ns

    def _position(self, stamp_ns: int) -> float:
        """The stamp in frame intervals from the epoch (integer part first: stamps are ~1.7e18 ns)."""
        whole = round(self.epoch_ns)
        return ((stamp_ns - whole) - (self.epoch_ns - whole)) / self.interval_ns

    def due_ns(self, slot: int) -> int:
        """When slot ``slot`` is due (ns, the stamps' clock)."""
        return round(self.epoch_ns + slot * self.interval_ns)

    def assign(self, stamp_ns: int) -> Assignment:
        """File the frame stamped ``stamp_ns`` (ns): its slot, or why it is refused; counted."""
        if self.epoch_ns is None:
            self._anchor(stamp_ns)
        assignment = self._assign(stamp_ns)
        if assignment.status != ACCEPTED:
            self.refused_in_a_row += 1
            if self.refused_in_a_row >= self.restart_after:
                self.counts["grid_restarts"] += 1
                self._anchor(stamp_ns)
                self.newest, self.filled, self.refused_in_a_row = None, set(), 0
                assignment = self._assign(stamp_ns)
        if assignment.status == ACCEPTED:
            self.refused_in_a_row = 0
        self.counts[COUNT_KEYS[assignment.status]] += 1
        return assignment

    def _assign(self, stamp_ns: int) -> Assignment:
        position = self._position(stamp_ns)
        slot = round(position)
        offset = position - slot
        period, index = divmod(slot, self.frames_per_period)

        def result(status: str) -> Assignment:
            return Assignment(status, slot, offset, period, index)

        if abs(offset) > self.tolerance:
            return result(OUT_OF_TOLERANCE)
        if slot < 0:
            return result(BEFORE_EPOCH)
        if self.newest is not None and slot < self.newest - self.window:
            return result(TOO_OLD)
        if slot in self.filled:
            return result(DUPLICATE)
        self.filled.add(slot)
        if self.newest is None or slot > self.newest:
            self.newest = slot
            self.filled = {s for s in self.filled if s >= slot - self.window}
        self.epoch_ns += self.gain * offset * self.interval_ns
        return result(ACCEPTED)


__all__ = ["ACCEPTED", "BEFORE_EPOCH", "COUNT_KEYS", "DUPLICATE", "OUT_OF_TOLERANCE", "TOO_OLD", "Assignment", "FrameGrid"]
