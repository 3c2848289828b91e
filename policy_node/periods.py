"""One robot's vision frames of its newest motion period, filed as the policy nodes file them (``policy_node`` and
``perceiving_policy``): ROS-free, the messages read by attribute.

A memory (``PeriodMemory``) holds ``episode``, ``period`` (the period being collected), ``frames`` (frame index →
message), ``ready`` (the newest complete period, frame order, not acted on yet) and ``decided`` (the last period
acted on). The caller
refuses malformed frames first (``envs.detection_messages.frame_problem``, ``period_problem``) and starts its
memory afresh when a frame of another episode comes; ``file_frame`` does the rest.
"""
from __future__ import annotations

from collections import Counter
from typing import Any


class PeriodMemory:
    """What a policy node keeps of one robot's frames between periods (module docstring)."""

    def __init__(self) -> None:
        self.episode: int | None = None
        self.period: int | None = None
        self.frames: dict[int, Any] = {}
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


def file_frame(memory: Any, msg: Any, counts: Counter[str]) -> None:
    """File a well-formed frame of the memory's episode: frames of a period older than the one being collected (or
    already complete or acted on) are stale; a complete period replaces an older one not yet acted on (counted as
    dropped), and so does a newer period's first frame replace an incomplete one."""
    period = msg.motion_period
    if ((memory.decided is not None and period <= memory.decided)
            or (memory.ready is not None and period <= memory.ready[0].motion_period)
            or (memory.frames and period < memory.period)):
        counts["frames_stale"] += 1
        return
    if memory.period != period:
        if memory.frames:
            counts["periods_dropped"] += 1          # an incomplete period that a newer one replaces
        memory.period, memory.frames = period, {}
    memory.frames[msg.frame_index] = msg
    if len(memory.frames) == msg.frames_per_period:
        if memory.ready is not None:
            counts["periods_dropped"] += 1          # complete but never acted on: stale now
        memory.ready = [memory.frames[k] for k in sorted(memory.frames)]
        memory.frames = {}


__all__ = ["PeriodMemory", "file_frame", "period_problem"]
