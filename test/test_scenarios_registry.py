"""The scenario registry (dynenv_ros/scenarios/, docs/decisions.md "A scenario registry"): every spelling a user,
a file or a message uses resolves to one scenario, an unknown one is refused with the choices, and the action
codec round-trips dynenv_msgs/Action's fields."""
from __future__ import annotations

import math

import numpy as np
import pytest
from dynenv_msgs.msg import Action, WorldState

from dynenv_ros.agent.export import policy_format
from dynenv_ros.agent.network import DynEnvAgent
from dynenv_ros.envs.teacher import action_indices
from dynenv_ros.scenarios import DRIVING, SCENARIOS, SOCCER, get_scenario, scenario_names
from dynenv_ros.soccer.actions import SoccerAction
from dynenv_ros.soccer.agent_actions import head_index, head_radians


@pytest.mark.parametrize("name, scenario", [("soccer", SOCCER), ("robocup", SOCCER), ("robocup_v0", SOCCER),
                                            ("driving", DRIVING)])
def test_every_spelling_resolves_to_its_scenario(name, scenario):
    assert get_scenario(name) is scenario


def test_canonical_names_and_the_spellings_kept_at_the_boundaries():
    assert [s.name for s in SCENARIOS] == ["soccer", "driving"]
    assert SOCCER.parameter_value == "robocup" and DRIVING.parameter_value == "driving"   # scenario:=robocup
    assert scenario_names() == ["soccer", "driving", "robocup", "robocup_v0"]


def test_world_state_codes_resolve():
    assert get_scenario(WorldState.SCENARIO_SOCCER) is SOCCER
    assert get_scenario(WorldState.SCENARIO_DRIVING) is DRIVING
    with pytest.raises(ValueError, match=r"unknown scenario code 7; codes are \[0, 1\]"):
        get_scenario(7)


@pytest.mark.parametrize("bad", ["Soccer", "football", "", None, True])
def test_an_unknown_name_is_refused_listing_the_choices(bad):
    with pytest.raises(ValueError) as error:
        get_scenario(bad)
    assert str(error.value) == (f"unknown scenario {bad!r}; choose one of 'soccer', 'driving', 'robocup', "
                                "'robocup_v0'")


def test_agent_names_of_each_scenario():
    assert SOCCER.agent_names(2) == ["team_a_0", "team_a_1", "team_b_0", "team_b_1"]
    assert DRIVING.agent_names(3) == ["car_0", "car_1", "car_2"]


def test_the_action_codec_round_trips_an_action_message():
    soccer = Action(**SOCCER.message_fields((1, 2, 0, -0.25)))
    assert (soccer.walk, soccer.turn, soccer.kick, soccer.head_yaw_delta) == (1, 2, 0, -0.25)
    assert SOCCER.action_fields(soccer) == (1, 2, 0, -0.25)
    driving = Action(**DRIVING.message_fields((0.5, 0.0, -1.5)))
    assert DRIVING.action_fields(driving) == (0.5, 0.0, -1.5)
    assert SOCCER.idle == (0, 0, 0, 0.0) and DRIVING.idle == (0.0, 1.0, 0.0)     # stand still; brake


def test_head_index_and_radians_invert_each_other():
    """3 units of 12.5 degrees each way (SoccerConfig's motion defaults): index 0..6 is -37.5..37.5 degrees."""
    step = math.radians(12.5)
    radians = head_radians(np.arange(7), 3, step)
    np.testing.assert_allclose(np.degrees(radians), [-37.5, -25, -12.5, 0, 12.5, 25, 37.5])
    np.testing.assert_array_equal(head_index(radians, 3, step), np.arange(7))
    # beyond the bound: clipped to the last index; between two: the nearer
    np.testing.assert_array_equal(head_index([-1.0, 1.0, 0.4 * step], 3, step), [0, 6, 3])


def test_head_radians_from_head_max_multiplies_before_it_divides():
    """dynenv-eval's order, (i − u)·head_max/u: with head_max 0.1 rad and 3 units, index 6 is 3·0.1 = 0.30000000000000004
    over 3 = 0.10000000000000002 rad, where the step's order gives 3·(0.1/3) = 0.1."""
    assert head_radians(6, 3, head_max=0.1) == 0.10000000000000002
    assert head_radians(0, 3, head_max=0.1) == -0.10000000000000002
    assert head_radians(6, 3, 0.1 / 3) == 0.1
    with pytest.raises(ValueError, match="give one of the head's step and its head_max"):
        head_radians(6, 3, 0.1 / 3, head_max=0.1)
    with pytest.raises(ValueError, match="give one of the head's step and its head_max"):
        head_radians(6, 3)


def test_a_teacher_rounds_a_float32_turn_in_float32():
    """Half a 12.5° step as a float32 (0x1.becde6p-4 rad) over the step is exactly 0.5 in float32, which rounds to
    even (no turn: index 3 of 0..6); in float64 it is just above 0.5 (index 4). The teachers divide a turn in its own
    type (``head_index(..., dtype=None)``); the default divides in float64."""
    step = math.radians(12.5)
    turn = np.float32(float.fromhex("0x1.becde6p-4"))
    assert head_index(turn, 3, step, dtype=None) == 3
    assert head_index(turn, 3, step) == 4
    assert action_indices(SoccerAction(head_yaw_delta=turn), step, 3) == (0, 0, 0, 3)
    assert action_indices(SoccerAction(head_yaw_delta=float(turn)), step, 3) == (0, 0, 0, 4)
    assert action_indices(SoccerAction(head_yaw_delta=-1.0), step, 3)[3] == 0        # beyond the bound: clipped
    assert action_indices(SoccerAction(head_yaw_delta=2 * step), step, 3)[3] == 5


def test_each_scenario_points_to_its_policy_format():
    """The agent layer's row of each scenario (agent.export, below the registry) names it as the registry does:
    the policy files' name and the nodes' parameter spelling."""
    for scenario in SCENARIOS:
        assert scenario.policy_format is policy_format(scenario.policy_metadata_name())
        assert scenario.policy_format.scenario == scenario.name
        assert scenario.policy_format.node_scenario == scenario.parameter_value
    with pytest.raises(ValueError, match="scenario must be 'soccer' or 'driving', got 'robocup'"):
        policy_format("robocup")        # a file's metadata names the canonical scenario only


def test_an_evaluation_refuses_an_agent_of_the_other_scenario():
    soccer, driving = DynEnvAgent(8), DynEnvAgent(8, scenario="driving")
    assert SOCCER.evaluation_problem(soccer) == "" and DRIVING.evaluation_problem(driving) == ""
    assert SOCCER.evaluation_problem(object()) == ""          # no scenario: an agent from before driving
    assert SOCCER.evaluation_problem(driving) == ("is a driving policy; soccer needs a policy trained with scenario: "
                                                  "robocup (evaluate it with --scenario driving)")
    assert DRIVING.evaluation_problem(soccer) == ("is a soccer policy; driving needs a policy trained with scenario: "
                                                  "driving (evaluate it with --scenario robocup)")
