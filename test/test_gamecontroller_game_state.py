"""The simulated game in the GameController's words (gamecontroller/game_state.py): phases to state and set play,
ball ownership to the kicking team and secondary time, the referee's penalties to SPL penalties."""
from __future__ import annotations

import ast
from pathlib import Path

import pytest

from dynenv_ros.core.object_classes import ObjectClass
from dynenv_ros.gamecontroller import packet as gc
from dynenv_ros.gamecontroller.game_state import game_control_data, penalty_code
from dynenv_ros.sim.ground_truth import BodyState, WorldSnapshot

REPO = Path(__file__).resolve().parent.parent
ROBOTS = (BodyState(id=0, class_id=ObjectClass.ROBOT, team=1), BodyState(id=1, class_id=ObjectClass.ROBOT, team=-1))


def snapshot(phase: int, owner: int = 0, owner_seconds: float = 0.0, remaining: float = 60.0) -> WorldSnapshot:
    return WorldSnapshot(scenario=0, episode_id=1, tick=0, tick_period=0.01, game_time=0.0, time_remaining=remaining,
                         phase=phase, ball_owner_team=owner, ball_owner_remaining=owner_seconds, objects=ROBOTS)


@pytest.mark.parametrize("phase, owner, seconds, expected", [
    # phase (WorldState.PHASE_*), owner, its seconds → (state, set play, kicking team, secondary time)
    (0, 0, 0.0, (0, 0, 255, 0)),          # INITIAL
    (1, 1, 10.0, (3, 0, 7, 10)),          # KICKOFF by team A: playing, no set play, A kicks, 10 s until free
    (1, -1, 9.01, (3, 0, 8, 10)),         # KICKOFF by team B, rounded up
    (2, 0, 0.0, (3, 0, 255, 0)),          # PLAYING, ball free
    (3, 1, 25.0, (3, 4, 7, 25)),          # KICK_IN
    (4, -1, 24.5, (3, 1, 8, 25)),         # GOAL_KICK
    (5, 1, 0.2, (3, 3, 7, 1)),            # CORNER_KICK
    (6, 0, 0.0, (4, 0, 255, 0)),          # FINISHED
])
def test_phases_become_the_gamecontrollers_state_and_set_play(phase, owner, seconds, expected):
    data = game_control_data(snapshot(phase, owner, seconds), players_per_team=1, team_numbers=(7, 8))
    assert (data.state, data.set_play, data.kicking_team, data.secondary_time) == expected
    assert (data.secs_remaining, data.first_half, data.players_per_team) == (60, True, 1)


def test_seconds_remaining_round_up_and_clamp_at_zero():
    assert game_control_data(snapshot(2, remaining=0.3), players_per_team=1, team_numbers=(7, 8)).secs_remaining == 1
    assert game_control_data(snapshot(6, remaining=0.0), players_per_team=1, team_numbers=(7, 8)).secs_remaining == 0


@pytest.mark.parametrize("kwargs, message", [
    (dict(players_per_team=2, team_numbers=(7, 8)), "team A has 1 robots"),
    (dict(players_per_team=1, team_numbers=(7, 7)), "two distinct numbers"),
    (dict(players_per_team=1, team_numbers=(0, 8)), "two distinct numbers"),
    (dict(players_per_team=1, team_numbers=(7, 255)), "two distinct numbers"),
    (dict(players_per_team=21, team_numbers=(7, 8)), "players_per_team must be"),
])
def test_inconsistent_requests_are_refused(kwargs, message):
    with pytest.raises(ValueError, match=message):
        game_control_data(snapshot(2), **kwargs)


def test_unknown_phase_and_driving_are_refused():
    with pytest.raises(ValueError, match="unknown game phase 9"):
        game_control_data(snapshot(9), players_per_team=1, team_numbers=(7, 8))
    driving = WorldSnapshot(scenario=1, episode_id=1, tick=0, tick_period=0.1, game_time=0.0, time_remaining=1.0,
                            phase=2)
    with pytest.raises(ValueError, match="soccer only"):
        game_control_data(driving, players_per_team=1, team_numbers=(7, 8))


def test_every_penalty_reason_of_the_simulator_has_an_spl_penalty():
    """The reasons soccer/world.py penalizes for (the literal texts of its ``_penalize`` calls) all map."""
    tree = ast.parse((REPO / "dynenv_ros" / "soccer" / "world.py").read_text())
    reasons = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Call) and getattr(node.func, "attr", "") == "_penalize" and len(node.args) == 2:
            arg = node.args[1]
            text = arg.value if isinstance(arg, ast.Constant) else "".join(
                v.value for v in arg.values if isinstance(v, ast.Constant)) if isinstance(arg, ast.JoinedStr) else ""
            reasons.append(text)
    assert len(reasons) == 5 and all(reasons)
    codes = {r: penalty_code(r + " (20 s)") for r in reasons}
    assert codes == {"left the field": gc.PENALTY_SPL_LEAVING_THE_FIELD,
                     "illegal defender": gc.PENALTY_SPL_ILLEGAL_POSITION,
                     "touched the ball during the opponents' free kick": gc.PENALTY_SPL_ILLEGAL_POSITION,
                     "pushing robot ": gc.PENALTY_SPL_PLAYER_PUSHING,
                     "fell  times without getting up": gc.PENALTY_SPL_INACTIVE_PLAYER}   # f-string: count left out
    assert penalty_code("waved at the referee") == gc.PENALTY_MANUAL == 15
