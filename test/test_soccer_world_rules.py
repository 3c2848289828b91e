"""Falls, pushing, penalties, outs, goals and ball ownership: each fires under its condition and not otherwise."""
import math

import pytest

from dynenv_ros.core.object_classes import ObjectStatus
from dynenv_ros.sim.reward_terms import RewardTerm
from dynenv_ros.soccer.actions import Kick, SoccerAction, Turn, Walk
from dynenv_ros.soccer.referee import Phase
from soccer_helpers import IDLE, idle_steps, kinds, make_world

FORWARD = SoccerAction(walk=Walk.FORWARD)


def test_random_fall_while_walking_is_unpunished_and_stops_the_robot():
    world = make_world(falls={"enabled": True, "p_walk": 1.0})
    world.place_robot(0, -2.0, 0.0, 0.0)
    result = world.step([FORWARD, IDLE])
    falls = kinds(result.events, "fall")
    assert [(e.robot, e.detail) for e in falls] == [(0, "fell while walking")]
    assert result.rewards[RewardTerm.RULE, 0] == 0.0
    assert world.robots[0].x == pytest.approx(-2.0, abs=1e-6)
    assert world.snapshot().objects[0].status & ObjectStatus.FALLEN


@pytest.mark.parametrize("action,setting", [(FORWARD, "p_walk"), (SoccerAction(turn=Turn.LEFT), "p_turn"),
                                            (SoccerAction(kick=Kick.LEFT_FOOT), "p_kick")])
def test_each_random_fall_needs_its_own_action(action, setting):
    world = make_world(falls={"enabled": True, "p_walk": 0.0, "p_turn": 0.0, "p_kick": 0.0, setting: 1.0})
    assert kinds(world.step([IDLE, IDLE]).events, "fall") == []
    assert len(kinds(world.step([action, IDLE]).events, "fall")) == 1


def test_no_random_falls_when_falls_are_disabled():
    world = make_world(falls={"enabled": False, "p_walk": 1.0, "p_turn": 1.0})
    events = idle_steps(world, 5, {0: SoccerAction(walk=Walk.FORWARD, turn=Turn.LEFT)})
    assert kinds(events, "fall") == []


def test_fallen_robot_gets_up_after_the_get_up_time_and_ignores_actions_meanwhile():
    world = make_world(falls={"enabled": True, "p_walk": 1.0, "p_fall_again": 0.0})
    world.place_robot(0, -2.0, 0.0, 0.0)
    world.step([FORWARD, IDLE])        # falls at the start of this period
    periods = round(world.config.falls.getup_seconds / world.config.period_seconds)
    events = idle_steps(world, periods - 2, {0: FORWARD})   # a fallen robot cannot walk (nor fall again)
    assert kinds(events, "get_up") == [] and world.robots[0].x == pytest.approx(-2.0, abs=1e-6)
    events = idle_steps(world, 1)
    assert [e.robot for e in kinds(events, "get_up")] == [0]
    assert not world.robots[0].rules.fallen


def test_three_falls_without_getting_up_give_a_penalty():
    world = make_world(falls={"enabled": True, "p_walk": 1.0, "p_fall_again": 1.0})
    world.place_robot(0, -2.0, 0.0, 0.0)
    events = world.step([FORWARD, IDLE]).events
    periods = 2 * round(world.config.falls.getup_seconds / world.config.period_seconds)
    ledger = 0.0
    for _ in range(periods):
        result = world.step([IDLE, IDLE])
        events += result.events
        ledger += result.rewards[RewardTerm.RULE, 0]
    assert len(kinds(events, "fall")) == 3
    penalties = kinds(events, "penalty")
    assert [e.robot for e in penalties] == [0] and "fell 3 times" in penalties[0].detail
    assert ledger == pytest.approx(-10.0)        # first penalty: 20 s at -0.5 per s; random falls cost nothing


CONTACT_FALL = "fell in a robot contact"


def _contact_world(falls, victim=2, actions=None, periods=4):
    """Robot 0 at (-1, 0) facing +x and ``victim`` 0.205 m ahead facing it (bodies 0.20 m across: a 5 mm gap), then
    ``periods`` periods of ``actions`` (robot index → action, the rest idle). Returns the events and each robot's
    summed rule reward."""
    world = make_world(players_per_team=2, falls={"enabled": True, "p_walk": 0.0, **falls})
    world.place_robot(0, -1.0, 0.0, 0.0)
    world.place_robot(victim, -1.0 + 0.205, 0.0, math.pi)
    events, rule = [], [0.0] * world.n_robots
    for _ in range(periods):
        result = world.step([(actions or {}).get(i, IDLE) for i in range(world.n_robots)])
        events += result.events
        rule = [total + float(r) for total, r in zip(rule, result.rewards[RewardTerm.RULE])]
    return events, rule


def _contact_falls(events):
    """Robots that fell in a robot contact (the proof that the bodies touched), in order."""
    return [e.robot for e in kinds(events, "fall") if e.detail == CONTACT_FALL]


# contact_base 0.5 (non-pusher falls within a few contact ticks), contact_base_pusher 1.0 (a pusher never falls)
VICTIM_FALLS = {"contact_base": 0.5, "contact_base_pusher": 1.0}
# the reverse: a pusher falls within a few contact ticks, a robot that is not pushing never falls
PUSHER_FALLS = {"contact_base": 1.0, "contact_base_pusher": 0.5}


def test_walking_into_an_opponent_who_falls_is_pushing():
    events, rule = _contact_world(VICTIM_FALLS, actions={0: FORWARD})
    assert _contact_falls(events) == [2]                               # the victim fell in the contact
    assert [e.robot for e in kinds(events, "fall")] == [2]             # the pusher's fall chance is 0 here
    assert [(e.robot, e.detail) for e in kinds(events, "penalty")] == [(0, "pushing robot 2 (20 s)")]
    # docs/soccer.md: the victim's fall is unpunished (it was not the pusher); the pusher's first penalty is
    # 20 s at -0.5 per second
    assert rule == [-10.0, 0.0, 0.0, 0.0]


def test_no_pushing_penalty_between_teammates():
    events, rule = _contact_world(VICTIM_FALLS, victim=1, actions={0: FORWARD})
    assert _contact_falls(events) == [1]                               # the contact happened, the teammate fell
    assert kinds(events, "penalty") == []
    assert rule == [0.0, 0.0, 0.0, 0.0]


def test_a_robot_that_stands_still_is_not_pushing_when_an_opponent_walks_into_it_and_falls():
    # Robot 0 does not walk; robot 2 walks into it and is the one that falls.
    events, rule = _contact_world(PUSHER_FALLS, actions={2: FORWARD})
    assert _contact_falls(events) == [2]                               # the contact happened, the walker fell
    assert kinds(events, "penalty") == []                              # robot 0 was not walking: no pushing
    assert rule == [0.0, 0.0, -2.0, 0.0]                               # fall as pusher: -2 (docs/soccer.md)


def test_a_standing_robot_that_falls_in_contact_gets_its_pusher_penalized():
    # The same contact, the other robot falls: robot 0 stood still (not walking into robot 2) and fell.
    events, rule = _contact_world(VICTIM_FALLS, actions={2: FORWARD})
    assert _contact_falls(events) == [0]
    assert [(e.robot, e.detail) for e in kinds(events, "penalty")] == [(2, "pushing robot 0 (20 s)")]
    assert rule == [0.0, 0.0, -10.0, 0.0]


def test_no_pushing_penalty_when_both_walk_into_each_other():
    # Both are pushers (base 0.5), so both fall; neither victim was "not walking into" the other: no penalty.
    events, rule = _contact_world(PUSHER_FALLS, actions={0: FORWARD, 2: FORWARD})
    assert sorted(_contact_falls(events)) == [0, 2]
    assert kinds(events, "penalty") == []
    assert rule == [-2.0, 0.0, -2.0, 0.0]


def test_pressing_against_a_goalpost_makes_a_robot_fall_with_a_fall_reward():
    world = make_world(falls={"enabled": True, "p_walk": 0.0, "goalpost_base": 0.5})
    post_x, post_y = world.config.field.goalposts[3]
    world.place_robot(0, post_x - 0.16, post_y, 0.0)
    total = 0.0
    events = []
    for _ in range(3):
        result = world.step([FORWARD, IDLE])
        events += result.events
        total += result.rewards[RewardTerm.RULE, 0]
    assert [e.detail for e in kinds(events, "fall")] == ["fell against a goalpost"]
    assert total == pytest.approx(world.config.rewards.fall)


def test_leaving_the_field_is_penalized_only_beyond_the_border():
    world = make_world()
    f = world.config.field
    world.place_robot(0, -f.half_length - f.border + 0.05, 0.0, 0.0)
    assert kinds(idle_steps(world, 1), "penalty") == []
    world.place_robot(0, -f.half_length - f.border - 0.05, 0.0, 0.0)
    penalties = kinds(idle_steps(world, 1), "penalty")
    assert [e.robot for e in penalties] == [0] and "left the field" in penalties[0].detail


def test_penalized_robot_waits_at_the_sideline_then_returns_and_durations_grow():
    world = make_world(players_per_team=2)
    f = world.config.field
    world.place_robot(0, -f.half_length - f.border - 0.1, 0.0, 0.0)
    result = world.step([IDLE] * 4)
    assert result.rewards[RewardTerm.RULE, 0] == pytest.approx(-10.0)
    r = world.robots[0]
    assert abs(r.y) == pytest.approx(f.half_width) and r.x < 0       # own half, on the sideline
    state = world.snapshot().objects[0]
    assert state.status & ObjectStatus.PENALIZED and state.penalty_remaining == pytest.approx(19.5, abs=0.11)
    world.place_robot(1, -f.half_length - f.border - 0.1, 1.0, 0.0)
    result = world.step([IDLE] * 4)
    assert result.rewards[RewardTerm.RULE, 1] == pytest.approx(-15.0)  # the team's second penalty lasts 30 s
    periods_left = round(19.0 / world.config.period_seconds)
    events = idle_steps(world, periods_left - 1, {0: FORWARD})
    assert kinds(events, "return") == [] and r.rules.penalized
    events = idle_steps(world, 2)
    assert [e.robot for e in kinds(events, "return")] == [0]
    assert not r.rules.penalized and abs(r.y) == pytest.approx(f.half_width)


def test_more_than_two_defenders_in_the_own_penalty_area_is_illegal():
    world = make_world(players_per_team=3)
    f = world.config.field
    inside_x = -f.half_length + 0.5
    world.place_robot(0, inside_x, -1.0, 0.0)
    world.place_robot(1, inside_x, 1.0, 0.0)
    assert kinds(idle_steps(world, 1), "penalty") == []
    world.place_robot(2, inside_x + 0.6, 0.0, 0.0)
    penalties = kinds(idle_steps(world, 1), "penalty")
    assert [(e.robot, e.detail.split(" (")[0]) for e in penalties] == [(2, "illegal defender")]


def test_three_robots_in_the_opponents_penalty_area_are_legal():
    world = make_world(players_per_team=3)
    f = world.config.field
    for i, y in enumerate((-1.0, 0.0, 1.0)):
        world.place_robot(i, f.half_length - 0.5, y, 0.0)
    assert kinds(idle_steps(world, 2), "penalty") == []


def _roll_ball_against(world, robot_index):
    r = world.robots[robot_index]
    world.place_ball(r.x + 0.4, r.y, vx=-1.0)


def test_touching_the_ball_during_the_opponents_free_kick_is_penalized():
    world = make_world()
    world.place_robot(0, -1.0, 0.0, 0.0)
    world.set_ball_owner(-1, 20.0)
    _roll_ball_against(world, 0)
    penalties = kinds(idle_steps(world, 1), "penalty")
    assert [e.robot for e in penalties] == [0] and "free kick" in penalties[0].detail


def test_the_owning_team_touching_the_ball_frees_it():
    world = make_world()
    world.place_robot(0, -1.0, 0.0, 0.0)
    world.set_ball_owner(1, 20.0)
    _roll_ball_against(world, 0)
    events = idle_steps(world, 1)
    assert kinds(events, "penalty") == []
    assert world.state.ball_owner == 0 and world.state.phase == Phase.PLAYING


def test_ownership_expires():
    world = make_world()
    world.set_ball_owner(-1, 1.0)
    idle_steps(world, 2)
    assert world.state.ball_owner == 0 and world.state.phase == Phase.PLAYING


def test_touch_chain_is_most_recent_first_without_duplicates():
    world = make_world(players_per_team=2)
    world.state.touched(0, 4)
    world.state.touched(2, 4)
    world.state.touched(0, 4)
    assert world.state.chain == [0, 2]
    for i in (1, 3, 2, 0, 1):
        world.state.touched(i, 4)
    assert world.state.chain == [1, 0, 2, 3]


def _out(world, x, y, vx, vy, last_toucher):
    world.state.chain[:] = [last_toucher]
    world.place_ball(x, y, vx, vy)
    return idle_steps(world, 1)


def test_ball_over_a_sideline_is_a_kick_in_for_the_other_team_moved_toward_the_touchers_goal():
    world = make_world()
    events = _out(world, 1.0, 2.9, 0.0, 1.0, last_toucher=0)      # team A touched last
    assert [e.detail for e in kinds(events, "out")] == ["KICK_IN"]
    assert world.ball_xy == pytest.approx((1.0 - world.config.ball.sideline_out_shift, 3.0))
    assert world.state.ball_owner == -1 and world.state.phase == Phase.KICK_IN
    assert world.ball.velocity.length == 0.0


def test_ball_over_the_goal_line_by_the_attackers_is_a_goal_kick():
    world = make_world()
    f = world.config.field
    _out(world, 4.4, 1.5, 1.0, 0.0, last_toucher=0)              # team A attacks +x
    assert world.state.phase == Phase.GOAL_KICK and world.state.ball_owner == -1
    assert world.ball_xy == pytest.approx((f.half_length - f.goal_area_length, 0.0))


def test_ball_over_the_own_goal_line_by_a_defender_is_a_corner():
    world = make_world()
    f = world.config.field
    _out(world, 4.4, -1.5, 1.0, 0.0, last_toucher=1)             # team B defends +x
    assert world.state.phase == Phase.CORNER_KICK and world.state.ball_owner == 1
    assert world.ball_xy == pytest.approx((f.half_length, -f.half_width))


def test_no_out_while_the_ball_is_on_the_line():
    world = make_world()
    world.place_ball(1.0, 3.0)
    assert kinds(idle_steps(world, 2), "out") == []


def test_goal_scores_pays_and_restarts_with_a_kickoff_for_the_other_team():
    world = make_world(players_per_team=2)
    world.state.chain[:] = [1, 0]
    world.place_ball(4.3, 0.1, 1.5, 0.0)
    result = world.step([IDLE] * 4)
    goals = kinds(result.events, "goal")
    assert [(g.team, g.detail) for g in goals] == [(1, "score 1:0")]
    snap = world.snapshot()
    assert (snap.score_team_a, snap.score_team_b) == (1, 0)
    # docs/soccer.md, primary term (docs/original.md §6.1, the same weights): the goal is worth ±25; every robot gets
    # 0.1 of its team's value, the touch chain [1, 0] gets 25·0.5^i, and of the losing side the robot closest to
    # the ball outside the chain (robot 3 at (1.6, -2.5); robot 2 at (1.0, -2.5); nobody within 1.5 m) gets half
    # the loss.
    primary = result.rewards[RewardTerm.PRIMARY]
    assert primary.tolist() == pytest.approx([0.1 * 25 + 25 * 0.5,      # robot 0: second in the chain
                                              0.1 * 25 + 25 * 1.0,      # robot 1: the scorer
                                              -0.1 * 25,                # robot 2: team share only
                                              -0.1 * 25 - 0.5 * 25])    # robot 3: closest loser, half the loss
    assert primary.tolist() == pytest.approx([15.0, 27.5, -2.5, -15.0])
    assert world.state.phase == Phase.KICKOFF and world.state.ball_owner == -1
    assert world.ball_xy == pytest.approx((0.0, 0.0), abs=0.05)
    assert world.state.chain == []
    for r in world.robots:                                        # everyone back in their own half
        assert r.team * r.x < 0


def test_goal_for_team_b_at_the_negative_end():
    world = make_world()
    world.state.chain[:] = [1]
    world.place_ball(-4.3, -0.3, -1.5, 0.0)
    result = world.step([IDLE, IDLE])
    assert [g.team for g in kinds(result.events, "goal")] == [-1]
    assert world.state.ball_owner == 1 and world.state.score == {1: 0, -1: 1}
    # robot 1 (team B) scored alone: team share + whole chain share; robot 0 is team A's only (closest) robot
    assert result.rewards[RewardTerm.PRIMARY].tolist() == pytest.approx([-0.1 * 25 - 0.5 * 25, 0.1 * 25 + 25])


def test_episode_is_truncated_after_its_time():
    world = make_world(episode_seconds=2.0)
    results = [world.step([IDLE, IDLE]) for _ in range(4)]
    assert [r.truncated for r in results] == [False, False, False, True]
    assert world.state.phase == Phase.FINISHED
    with pytest.raises(RuntimeError, match="reset"):
        world.step([IDLE, IDLE])


@pytest.mark.parametrize("players", [1, 2, 5])
@pytest.mark.parametrize("kicking_team", [1, -1])
def test_kickoff_puts_the_keeper_in_goal_the_striker_at_the_ball_and_everyone_in_their_half(players, kicking_team):
    world = make_world(players_per_team=players)
    world.reset(seed=4, kickoff_team=kicking_team)
    f = world.config.field
    for r in world.robots:
        assert r.team * r.x < 0 and abs(r.y) < f.half_width
        assert math.cos(r.yaw) == pytest.approx(r.team)           # facing the opponent goal
    for team in (1, -1):
        mates = [r for r in world.robots if r.team == team]
        striker = mates[0] if players == 1 else mates[1]
        distance = math.hypot(striker.x, striker.y)
        assert distance < 0.9 if team == kicking_team else f.center_circle_radius < distance < 2.5
        if players > 1:
            assert mates[0].team * mates[0].x < -f.half_length + f.penalty_area_length   # slot 0 keeps goal
    assert world.state.ball_owner == kicking_team and world.state.phase == Phase.KICKOFF


@pytest.mark.parametrize("settings,message", [({"robot_mass": 0.0}, "robot_mass must be positive"),
                                              ({"ball": {"radius": 0.0}}, "ball.radius must be positive"),
                                              ({"kick": {"periods": 0}}, "at least 1")])
def test_settings_that_would_break_the_physics_are_refused(settings, message):
    with pytest.raises(ValueError, match=message):
        make_world(**settings)
