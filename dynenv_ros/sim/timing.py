"""Clocks and rates: physics ticks, vision frames and motion periods in exact integer ratios.

A motion period (one high-level action) spans several vision frames, each of which spans several physics ticks.
Sim time is kept as an integer tick count and converted exactly (``fractions.Fraction``), so it never drifts.
"""
from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from fractions import Fraction

NANOSECONDS_PER_SECOND = 1_000_000_000
MAX_FRAMES_PER_PERIOD = 255


@dataclass(frozen=True)
class Rates:
    """Defaults follow DynEnv: 100 Hz physics, a frame every 10 ticks (10 Hz), an action every 50 ticks (2 Hz)."""
    physics_hz: float = 100.0
    vision_period_ticks: int = 10
    motion_period_ticks: int = 50

    def __post_init__(self) -> None:
        if not (math.isfinite(self.physics_hz) and self.physics_hz > 0):
            raise ValueError(f"physics_hz must be a positive number, got {self.physics_hz}")
        for name in ("vision_period_ticks", "motion_period_ticks"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ValueError(f"{name} must be a positive integer, got {value!r}")
        if self.motion_period_ticks % self.vision_period_ticks:
            raise ValueError(f"a motion period ({self.motion_period_ticks} ticks) must hold a whole number of "
                             f"vision periods ({self.vision_period_ticks} ticks)")
        if self.motion_period_ticks // self.vision_period_ticks > MAX_FRAMES_PER_PERIOD:
            raise ValueError(f"at most {MAX_FRAMES_PER_PERIOD} vision frames per motion period (DetectionArray."
                             f"frame_index is a uint8), got {self.motion_period_ticks // self.vision_period_ticks}")

    @classmethod
    def from_hz(cls, physics_hz: float, vision_hz: float, motion_hz: float) -> "Rates":
        """Rates given as frequencies; each must divide the faster one exactly."""
        ticks = {}
        for name, hz in (("vision_hz", vision_hz), ("motion_hz", motion_hz)):
            if not (math.isfinite(hz) and hz > 0):
                raise ValueError(f"{name} must be a positive number, got {hz}")
            ratio = physics_hz / hz
            if ratio < 1 or abs(ratio - round(ratio)) > 1e-9:
                raise ValueError(f"{name}={hz} does not divide physics_hz={physics_hz} into a whole number of "
                                 f"ticks ({ratio:.4g})")
            ticks[name] = round(ratio)
        return cls(physics_hz, ticks["vision_hz"], ticks["motion_hz"])

    @functools.cached_property
    def tick_period(self) -> Fraction:
        """Seconds per physics tick, exactly (computed once: worlds ask for it every period)."""
        return 1 / Fraction(self.physics_hz).limit_denominator(10**9)

    @functools.cached_property
    def tick_seconds(self) -> float:
        return float(self.tick_period)

    @property
    def vision_hz(self) -> float:
        return self.physics_hz / self.vision_period_ticks

    @property
    def motion_hz(self) -> float:
        return self.physics_hz / self.motion_period_ticks

    @property
    def frames_per_period(self) -> int:
        return self.motion_period_ticks // self.vision_period_ticks

    def vision_tick_offsets(self) -> tuple[int, ...]:
        """Ticks into a motion period after which each vision frame is taken (the last one ends the period)."""
        return tuple(self.vision_period_ticks * (k + 1) for k in range(self.frames_per_period))

    def time_of_tick(self, tick: int) -> tuple[int, int]:
        """Sim time after ``tick`` ticks as (seconds, nanoseconds), the form of builtin_interfaces/Time."""
        if tick < 0:
            raise ValueError(f"tick must be non-negative, got {tick}")
        total_ns = round(tick * self.tick_period * NANOSECONDS_PER_SECOND)
        return divmod(total_ns, NANOSECONDS_PER_SECOND)
