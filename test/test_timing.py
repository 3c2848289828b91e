"""Clocks and rates: integer ratios enforced, frame instants per motion period, drift-free sim time."""
from __future__ import annotations

import pytest

from dynenv_ros.sim.timing import Rates


def test_defaults_are_dynenv_rates():
    rates = Rates()
    assert (rates.tick_seconds, rates.vision_hz, rates.motion_hz) == (0.01, 10.0, 2.0)
    assert rates.frames_per_period == 5
    assert rates.vision_tick_offsets() == (10, 20, 30, 40, 50)


def test_from_hz_accepts_exact_ratios():
    rates = Rates.from_hz(physics_hz=120.0, vision_hz=30.0, motion_hz=2.0)
    assert (rates.vision_period_ticks, rates.motion_period_ticks, rates.frames_per_period) == (4, 60, 15)


@pytest.mark.parametrize("kwargs, reason", [
    ({"vision_period_ticks": 7}, "whole number of vision periods"),
    ({"vision_period_ticks": 0}, "positive integer"),
    ({"motion_period_ticks": 2.5}, "positive integer"),
    ({"physics_hz": float("nan")}, "positive number"),
    ({"physics_hz": -100.0}, "positive number"),
])
def test_invalid_rates_are_refused_with_reason(kwargs, reason):
    with pytest.raises(ValueError, match=reason):
        Rates(**kwargs)


def test_from_hz_refuses_inexact_ratio():
    with pytest.raises(ValueError, match="vision_hz=30.0 does not divide physics_hz=100.0"):
        Rates.from_hz(physics_hz=100.0, vision_hz=30.0, motion_hz=2.0)


def test_sim_time_does_not_drift():
    rates = Rates.from_hz(physics_hz=30.0, vision_hz=30.0, motion_hz=1.0)  # tick = 1/30 s, not exact in binary
    assert rates.time_of_tick(30 * 3600) == (3600, 0)
    assert rates.time_of_tick(1) == (0, 33_333_333)
    assert Rates().time_of_tick(12_000) == (120, 0)
    with pytest.raises(ValueError):
        Rates().time_of_tick(-1)


def test_more_frames_per_period_than_a_detection_array_can_number_are_refused():
    with pytest.raises(ValueError, match="at most 255 vision frames"):
        Rates(physics_hz=100.0, vision_period_ticks=1, motion_period_ticks=300)
