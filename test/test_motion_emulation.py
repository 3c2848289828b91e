"""The motion emulator's engines (soccer/motion_emulation.py): one action per simulator period from the newest
commands, sent when the head command answering the period's last frame came or after the timeout."""
from __future__ import annotations

import math

import pytest

from dynenv_ros.soccer.config import MotionConfig
from dynenv_ros.soccer.motion_commands import StepSpeeds
from dynenv_ros.soccer.motion_emulation import EngineLatch

MS = 1_000_000
STEP = math.radians(12.5)


def latch(timeout_ms=1000, twist_age_ms=2000):
    return EngineLatch(StepSpeeds.of(MotionConfig(), 0.5), 3 * STEP, 50 * MS, timeout_ms * MS, twist_age_ms * MS)


def test_the_action_waits_for_the_head_command_answering_the_period():
    engines = latch()
    engines.period_ended(episode=1, period=3, stamp_ns=2000 * MS, now_ns=0)
    engines.walk_target(0.11, 0.0, -0.2, now_ns=1 * MS)
    assert engines.due(2 * MS) is None                           # no answer yet, no timeout yet
    assert engines.head_command(1500 * MS, 0.5) == ""              # an older period's head command: not the answer
    assert engines.due(3 * MS) is None
    engines.head_command(2000 * MS, 2 * STEP / 0.5)
    due = engines.due(4 * MS)
    assert (due.episode, due.period, due.why) == (1, 4, "answered")
    assert due.action[:3] == (1, 2, 0) and due.action[3] == pytest.approx(2 * STEP)
    assert engines.due(5 * MS) is None                           # one action per period


def test_without_an_answer_the_engines_keep_the_walk_target_and_the_head_holds():
    engines = latch(timeout_ms=100)
    engines.walk_target(0.0, 0.072, 0.0, now_ns=0)
    engines.head_command(0, 1.0)
    engines.period_ended(1, 5, 3000 * MS, now_ns=10 * MS)
    assert engines.due(100 * MS) is None
    due = engines.due(110 * MS)
    assert due.why == "timeout" and due.action == (3, 0, 0, 0.0)


def test_no_timeout_before_anyone_commands_and_the_initial_period_is_answered_at_once():
    engines = latch(timeout_ms=10)
    engines.period_ended(1, 0, 0, now_ns=0)
    assert engines.due(10_000 * MS, commander=False) is None     # the stack is not up: wait
    due = engines.due(10_001 * MS, commander=True)
    assert (due.period, due.why, due.action) == (1, "initial", (0, 0, 0, 0.0))


def test_a_kick_request_is_used_once_and_an_old_walk_target_stops_the_robot():
    engines = latch(timeout_ms=10, twist_age_ms=500)
    engines.walk_target(0.11, 0.0, 0.0, now_ns=0)
    engines.kick_request(use_left_foot=False)
    engines.period_ended(1, 1, 500 * MS, now_ns=0)
    engines.head_command(500 * MS, 0.0)
    assert engines.due(1 * MS).action[:3] == (0, 0, 2)
    engines.period_ended(1, 2, 1000 * MS, now_ns=100 * MS)
    assert engines.due(110 * MS).action[:3] == (1, 0, 0)          # timeout: the walk target, no kick again
    engines.period_ended(1, 3, 1500 * MS, now_ns=600 * MS)
    assert engines.due(610 * MS).action[:3] == (0, 0, 0)          # the target is 610 ms old: stand


def test_commands_that_are_not_commands_are_refused():
    engines = latch()
    assert "not finite" in engines.walk_target(math.nan, 0.0, 0.0, now_ns=0)
    assert "beyond" in engines.walk_target(3.0, 0.0, 0.0, now_ns=0)
    assert "not finite" in engines.head_command(0, math.inf)
    assert engines.twist == (0.0, 0.0, 0.0) and engines.head is None
