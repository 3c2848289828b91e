"""The per-scenario tables of the layers that cannot ask the registry (issue 40; docs/decisions.md, "A scenario
registry"): ``render``, ``envs`` and the worlds lie below it, and the launcher keeps it (and torch) out of its start-up,
so each finds a scenario's piece in a table of its own, keyed by what that layer is given (a WorldState's scenario
code, a layout's name, a --scenario choice). Every registered scenario has its row in each, and nothing else does.
WorldState.SCENARIO_SOCCER is 0 and SCENARIO_DRIVING 1 (dynenv_msgs/msg/WorldState.msg)."""
from __future__ import annotations

import pytest

from dynenv_ros.driving.config import is_driving_world
from dynenv_ros.envs.detection_messages import SIDES
from dynenv_ros.envs.padded_layout import PaddedLayout
from dynenv_ros.render.replay import REPLAYS, DrivingReplay, SoccerReplay, replay_of
from dynenv_ros.scenarios import DRIVING, SCENARIOS, SOCCER
from dynenv_ros.soccer.config import is_soccer_world


def test_each_world_has_its_replay_and_an_unknown_code_is_replayed_as_soccer():
    assert REPLAYS == {SOCCER.world_code: SoccerReplay, DRIVING.world_code: DrivingReplay}
    assert (replay_of(0), replay_of(1)) == (SoccerReplay, DrivingReplay)
    assert replay_of(7) is SoccerReplay and replay_of(None) is SoccerReplay


def test_each_world_knows_its_own_code_and_no_other():
    assert [is_soccer_world(code) for code in (0, 1, 2)] == [True, False, False]
    assert [is_driving_world(code) for code in (0, 1, 2)] == [False, True, False]
    assert is_soccer_world(SOCCER.world_code) and is_driving_world(DRIVING.world_code)


def test_every_layout_has_what_it_reads_from_the_messages_and_only_soccers_carries_the_pose():
    assert sorted(SIDES) == sorted(s.layout_spec().scenario for s in SCENARIOS)
    assert PaddedLayout(spec=SOCCER.layout_spec(), pose=True).pose
    with pytest.raises(ValueError, match="pose estimate"):
        PaddedLayout(spec=DRIVING.layout_spec(), pose=True)


def test_every_scenario_has_its_game_in_dynenv_play_and_in_the_main_job():
    from dynenv_ros import main_job
    from dynenv_ros.envs import play
    spellings = sorted(s.parameter_value for s in SCENARIOS)       # what both take: 'robocup', 'driving'
    assert sorted(play.GAMES) == sorted(play.SCENARIOS) == spellings
    assert sorted(main_job.GAMES) == sorted(main_job.SCENARIOS) == spellings
    settings = [set(game.settings) for game in main_job.GAMES.values()]
    assert not set.intersection(*settings)        # a setting only one scenario's game uses is one game's
