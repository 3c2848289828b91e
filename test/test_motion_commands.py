"""A discrete action as a walk engine's twist, a kick request and a head command, and back (issue 41,
soccer/motion_commands.py). The expected numbers are docs/soccer.md's step sizes over its 0.5 s motion period."""
from __future__ import annotations

import math

import pytest

from dynenv_ros.soccer.config import MotionConfig
from dynenv_ros.soccer.motion_commands import MotionCommand, StepSpeeds, action_of, command_of

# docs/soccer.md, "Actions": forward 0.055 m, backward 0.036 m, sideways 0.036 m, turn 0.1 rad per period; a period
# is 50 ticks of 100 Hz = 0.5 s; the head turns at most 3 × 12.5° per period.
PERIOD = 0.5
SPEEDS = StepSpeeds.of(MotionConfig(), PERIOD)
HEAD_MAX = math.radians(37.5)
TWISTS = {  # (walk, turn) -> (linear.x, linear.y, angular.z)
    (0, 0): (0.0, 0.0, 0.0), (1, 0): (0.11, 0.0, 0.0), (2, 0): (-0.072, 0.0, 0.0), (3, 0): (0.0, 0.072, 0.0),
    (4, 0): (0.0, -0.072, 0.0), (0, 1): (0.0, 0.0, 0.2), (0, 2): (0.0, 0.0, -0.2), (1, 2): (0.11, 0.0, -0.2),
    (3, 1): (0.0, 0.072, 0.2)}


@pytest.mark.parametrize("walk_turn, twist", sorted(TWISTS.items()))
def test_each_walk_and_turn_is_its_step_over_the_period(walk_turn, twist):
    command = command_of(*walk_turn, 0, 0.0, SPEEDS)
    assert (command.vx, command.vy, command.wz) == pytest.approx(twist, abs=1e-12)
    assert command.kick == 0 and command.head_rate == 0.0


def test_a_kick_stands_and_asks_for_the_foot_and_a_kick_while_walking_walks():
    assert command_of(0, 0, 1, 0.0, SPEEDS) == MotionCommand(0.0, 0.0, 0.0, 1, 0.0)
    assert command_of(0, 0, 2, 0.0, SPEEDS).kick == 2
    walking = command_of(1, 0, 2, 0.0, SPEEDS)         # the motion layer kicks only standing: it walks
    assert walking.kick == 0 and walking.vx == pytest.approx(0.11)


def test_the_head_turns_at_its_delta_over_the_period():
    step = math.radians(12.5)
    assert command_of(0, 0, 0, 2 * step, SPEEDS).head_rate == pytest.approx(2 * step / PERIOD)
    assert command_of(0, 0, 0, -step, SPEEDS).head_rate == pytest.approx(-0.436332, abs=1e-6)


@pytest.mark.parametrize("walk", range(5))
@pytest.mark.parametrize("turn", range(3))
@pytest.mark.parametrize("kick", range(3))
@pytest.mark.parametrize("head_index", range(7))
def test_every_discrete_action_comes_back_from_its_commands(walk, turn, kick, head_index):
    head = (head_index - 3) * math.radians(12.5)
    back = action_of(command_of(walk, turn, kick, head, SPEEDS), SPEEDS, HEAD_MAX)
    moves = walk or turn
    assert back[:3] == (walk, turn, 0 if moves else kick)
    assert back[3] == pytest.approx(head, abs=1e-12)


@pytest.mark.parametrize("vx, vy, wz, expected", [
    (0.06, 0.0, 0.0, (1, 0)),          # more than half of 0.11 m/s: a forward step
    (0.05, 0.0, 0.0, (0, 0)),          # less: none
    (-0.04, 0.0, 0.0, (2, 0)),         # more than half of 0.072 backward
    (0.0, -0.05, 0.0, (4, 0)),
    (0.08, 0.07, 0.0, (3, 0)),         # 0.08/0.11 = 0.73 along x, 0.07/0.072 = 0.97 along y: sideways
    (0.2, 0.0, 0.5, (1, 1)),           # faster than a step: still one step (the motion layer has one speed)
    (0.0, 0.0, -0.11, (0, 2)),         # more than half of 0.2 rad/s clockwise
])
def test_a_stacks_walk_target_is_quantised_to_the_steps(vx, vy, wz, expected):
    assert action_of(MotionCommand(vx, vy, wz), SPEEDS, HEAD_MAX)[:2] == expected


def test_a_pending_kick_overrides_the_walk_target_and_the_head_is_bounded():
    assert action_of(MotionCommand(0.11, 0.0, 0.2, 1, 0.0), SPEEDS, HEAD_MAX)[:3] == (0, 0, 1)
    assert action_of(MotionCommand(head_rate=10.0), SPEEDS, HEAD_MAX)[3] == pytest.approx(HEAD_MAX)


@pytest.mark.parametrize("command, reason", [
    (MotionCommand(vx=math.nan), "not finite"), (MotionCommand(wz=math.inf), "not finite"),
    (MotionCommand(vx=1.5), "beyond"), (MotionCommand(head_rate=math.nan), "not finite")])
def test_commands_no_robot_can_follow_are_refused_with_the_reason(command, reason):
    with pytest.raises(ValueError, match=reason):
        action_of(command, SPEEDS, HEAD_MAX)
    with pytest.raises(ValueError, match="positive"):
        StepSpeeds.of(MotionConfig(), 0.0)
