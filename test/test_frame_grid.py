"""Frames to slots by stamp (dynenv_ros/ros/frame_grid.py): the nearest slot within a tolerance, on a grid centred
on the camera's own phase, with duplicates, old frames and off-grid stamps refused and counted."""
from __future__ import annotations

import random

import pytest

from dynenv_ros.ros.frame_grid import ACCEPTED, BEFORE_EPOCH, DUPLICATE, OUT_OF_TOLERANCE, TOO_OLD, FrameGrid

MS = 1_000_000
BASE = 1_700_000_000 * 1_000_000_000          # a wall-clock stamp: the grid must keep ns precision there


def test_round_numbering_breaks_near_half_an_interval_and_the_grid_does_not():
    """The issue's camera: 10 Hz, frames due at half an interval past the 100 ms grid, ±6 ms of jitter. round()
    gives duplicates and gaps; the grid anchored on the first stamp's phase gives every slot exactly once."""
    rng = random.Random(0)
    stamps = [BASE + 50 * MS + n * 100 * MS + rng.randint(-6 * MS, 6 * MS) for n in range(200)]
    rounded = [round(s * 10 / 1e9) for s in stamps]
    assert len(set(rounded)) < 190                         # the old numbering: many duplicates (and gaps)
    grid = FrameGrid(10.0, 5)
    got = [grid.assign(s) for s in stamps]
    assert all(a.status == ACCEPTED for a in got)
    slots = [a.slot for a in got]
    assert slots == list(range(slots[0], slots[0] + 200))
    assert abs(slots[0] - round((BASE + 50 * MS) / 100 / MS)) <= 1       # absolute numbering: slot ≈ stamp · hz
    assert all(abs(a.offset) < 0.13 for a in got)
    assert grid.counts == {"frames_accepted": 200}


def test_periods_and_indices_come_from_the_slot():
    grid = FrameGrid(10.0, 5, epoch_s=0.0)                # the plain round(stamp · hz) numbering
    a = grid.assign(12 * 10**9 + 300 * MS)
    assert (a.status, a.slot, a.period, a.index) == (ACCEPTED, 123, 24, 3)
    assert grid.due_ns(123) == 12_300 * MS
    later = FrameGrid(10.0, 5, epoch_s=20.0)                # a fixed epoch after the camera's stamps
    assert later.assign(12 * 10**9).status == BEFORE_EPOCH and later.counts == {"frames_before_epoch": 1}


def test_duplicates_old_frames_and_off_grid_stamps_are_refused_and_counted():
    grid = FrameGrid(10.0, 5, tolerance=0.3, gain=0.0)
    first = grid.assign(BASE)
    assert first.status == ACCEPTED
    assert grid.assign(BASE + 2 * MS).status == DUPLICATE                  # a second frame for slot 0
    assert grid.assign(BASE + 150 * MS).status == OUT_OF_TOLERANCE         # half-way between slots 1 and 2
    assert grid.assign(BASE + 1500 * MS).status == ACCEPTED                # slot 15
    assert grid.assign(BASE + 400 * MS).status == TOO_OLD                  # slot 4: 11 behind, window 10
    late = grid.assign(BASE + 700 * MS)                                   # slot 7: late, but inside the window
    assert late.status == ACCEPTED and late.slot == first.slot + 7
    assert grid.counts == {"frames_accepted": 3, "frames_duplicate": 1, "frames_out_of_tolerance": 1,
                           "frames_too_old": 1}


def test_phase_tracking_follows_a_camera_whose_clock_runs_slow():
    """29.9 Hz against a nominal 30 Hz drifts a full interval in 10 s; the tracked grid keeps every frame."""
    real = 1e9 / 29.9
    tracked, fixed = FrameGrid(30.0, 3), FrameGrid(30.0, 3, gain=0.0, restart_after=10**6)
    stamps = [BASE + round(n * real) for n in range(600)]
    assert all(tracked.assign(s).status == ACCEPTED for s in stamps)
    assert sum(fixed.assign(s).status == ACCEPTED for s in stamps) < 0.85 * len(stamps)   # ~a fifth refused


def test_a_camera_whose_timing_changes_re_anchors_the_grid():
    """A restarted driver with another phase: refused frames in a row make the grid start again on the new phase."""
    grid = FrameGrid(10.0, 5, tolerance=0.2, gain=0.0)
    for n in range(10):
        assert grid.assign(BASE + n * 100 * MS).status == ACCEPTED
    shifted = [grid.assign(BASE + 2000 * MS + 50 * MS + n * 100 * MS) for n in range(20)]
    assert grid.counts["grid_restarts"] == 1
    assert [a.status for a in shifted[:9]] == [OUT_OF_TOLERANCE] * 9
    assert all(a.status == ACCEPTED for a in shifted[9:])


def test_bad_settings_are_refused():
    with pytest.raises(ValueError, match="tolerance"):
        FrameGrid(10.0, 5, tolerance=0.6)
    with pytest.raises(ValueError, match="hz"):
        FrameGrid(0.0, 5)
