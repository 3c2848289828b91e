"""One robot's vision frames of its newest motion period, filed as the policy nodes file them (``policy_node`` and
``perceiving_policy``): ROS-free, the messages read by attribute.

A memory (``PeriodMemory``) holds ``episode``, ``period`` (the period being collected), ``frames`` (frame index →
message), ``due`` (when the period being collected is due on the node's clock, ns: the policy node's
``decision_deadline``), ``ready`` (the newest complete period, frame order, not acted on yet) and ``decided`` (the
last period acted on). The caller refuses malformed frames first (``envs.detection_messages.frame_problem``,
``period_problem``) and starts its memory afresh when a frame of another episode comes; ``file_frame`` does the
rest. A second frame for a frame index already filed is a duplicate: the first is kept (counted,
``frames_duplicate``).

Partial periods (``close``: a callable that fills an incomplete period's gaps, ``partial_periods.fill``): a newer
period's first frame closes the incomplete period being collected — it becomes ready with its gaps filled
(``periods_partial``) instead of being dropped — and ``close_period`` does the same at the deadline.
"""
from __future__ import annotations

from collections import Counter
from collections.abc import Callable
from typing import Any

Close = Callable[[dict[int, Any]], list[Any]]     # an incomplete period's frames -> the period, gaps filled


class PeriodMemory:
    """What a policy node keeps of one robot's frames between periods (module docstring)."""

    def __init__(self) -> None:
        self.episode: int | None = None
        self.period: int | None = None
        self.frames: dict[int, Any] = {}
        self.due: int | None = None
        self.ready: list[Any] | None = None
        self.decided: int | None = None


def period_problem(memory: Any, msg: Any) -> str:
    """Why ``msg`` cannot join the frames of its period collected so far ('' if it can)."""
    if memory.frames and msg.motion_period == memory.period:
        first = next(iter(memory.frames.values()))
        if msg.frames_per_period != first.frames_per_period:
            return (f"frames_per_period {msg.frames_per_period} differs from the period's other frames "
                    f"({first.frames_per_period})")
    return ""


def file_frame(memory: Any, msg: Any, counts: Counter[str], close: Close | None = None) -> bool:
    """File a well-formed frame of the memory's episode: frames of a period older than the one being collected (or
    already complete or acted on) are stale; a complete period replaces an older one not yet acted on (counted as
    dropped), and so does a newer period's first frame replace an incomplete one — or, with ``close``, make it
    ready with its gaps filled. Returns True when the frame joined the period being collected and left it
    incomplete (the caller's cue to update ``memory.due``)."""
    period = msg.motion_period
    if ((memory.decided is not None and period <= memory.decided)
            or (memory.ready is not None and period <= memory.ready[0].motion_period)
            or (memory.frames and period < memory.period)):
        counts["frames_stale"] += 1
        return False
    if memory.period != period:
        if memory.frames and close is not None:
            close_period(memory, counts, close)
        elif memory.frames:
            counts["periods_dropped"] += 1          # an incomplete period that a newer one replaces
        memory.period, memory.frames, memory.due = period, {}, None
    if msg.frame_index in memory.frames:
        counts["frames_duplicate"] += 1             # the first one is kept
        return False
    memory.frames[msg.frame_index] = msg
    if len(memory.frames) == msg.frames_per_period:
        _make_ready(memory, [memory.frames[k] for k in sorted(memory.frames)], counts)
        return False
    return True


def close_period(memory: Any, counts: Counter[str], close: Close) -> None:
    """Make the incomplete period being collected ready, its gaps filled by ``close`` (its deadline passed, or a
    newer period began)."""
    _make_ready(memory, close(memory.frames), counts)
    counts["periods_partial"] += 1


def _make_ready(memory: Any, period: list[Any], counts: Counter[str]) -> None:
    if memory.ready is not None:
        counts["periods_dropped"] += 1              # complete but never acted on: stale now
    memory.ready = period
    memory.frames, memory.due = {}, None


__all__ = ["Close", "PeriodMemory", "close_period", "file_frame", "period_problem"]
