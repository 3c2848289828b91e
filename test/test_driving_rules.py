"""Driving rules and rewards by term, with the original's magnitudes (docs/original.md §3 collisions, §6.2).

Unit conversions used below (0.1 m per px): a crash costs |v|/5 with v in px/s = 2·|v| with v in m/s; opposing-lane
driving costs |v|/10000 per 10 ms tick (v in px/s) = 0.1 per metre; progress pays Δpx/50 = 0.2 per metre; reaching
the destination at tick t pays (6000 − t)/100.
"""
import math

import numpy as np
import pytest

from dynenv_ros.core.object_classes import ObjectClass, ObjectStatus
from dynenv_ros.driving.config import DrivingConfig
from dynenv_ros.driving.world import DrivingWorld
from dynenv_ros.sim.reward_terms import RewardTerm

COAST = [0.0, 0.0, 0.0]                 # continuous: no throttle, no brake, straight
HOLD = [0.0, 1.0, 0.0]                  # full brake
EAST, NORTH, WEST, SOUTH = 0.0, math.pi / 2, math.pi, -math.pi / 2
HALF_LENGTH = 1.5                       # the single car type of these tests (type 1: 1800 kg, 3 x 1.2 m, power 4)


def make_world(n_cars=2, pedestrians=0, teams=1, **settings):
    config = DrivingConfig.from_mapping({
        "n_cars": n_cars, "teams": teams, "action_mode": "continuous",
        "pedestrians": {"count_min": pedestrians, "count_max": pedestrians},
        "obstacles": {"count_min": 0, "count_max": 0},
        "cars": {"masses": [1800.0], "half_widths": [0.6], "half_lengths": [HALF_LENGTH], "powers": [4.0]},
        **settings})
    world = DrivingWorld(config, seed=0)
    for i in range(n_cars):   # parked in their right lanes on the west road, far from each other
        world.place_car(i, 5.0 + 12.0 * i, 48.25, EAST)
        world.set_goal(i, 3)
    return world


def step(world, overrides=None, default=HOLD):
    actions = [(overrides or {}).get(i, default) for i in range(world.n_cars)]
    return world.step(actions)


def kinds(events, kind):
    return [e for e in events if e.kind == kind]


def car_state(world, i):
    return next(o for o in world.snapshot().objects if o.class_id == ObjectClass.CAR and o.id == i)


def test_reaching_the_destination_pays_the_seconds_left_and_the_car_leaves():
    world = make_world()
    world.place_car(0, 166.0, 48.25, EAST, speed=5.0)          # 4 m before the east end, its destination
    events = []
    for _ in range(20):
        result = step(world, {0: COAST})
        events += result.events
        if kinds(result.events, "goal"):
            break
    goal = kinds(events, "goal")
    assert [e.robot for e in goal] == [0] and goal[0].tick == world.tick
    assert result.rewards[RewardTerm.PRIMARY, 0] == pytest.approx((6000 - world.tick) / 100)
    assert result.rewards[RewardTerm.PRIMARY, 1] == 0.0
    assert world.cars[0].x > 171.0                             # past the end by more than 10 px
    state = car_state(world, 0)
    assert state.status == ObjectStatus.FINISHED | ObjectStatus.AT_GOAL
    assert (state.goal_x, state.goal_y) == (170.0, 50.0) and (state.vx, state.vy) == (0.0, 0.0)
    assert not world.cars[0].in_space                          # gone: nothing can run into it
    result = step(world, {0: [1.0, 0.0, 0.0]})                 # a finished car ignores actions, earns nothing
    assert result.rewards[:, 0].tolist() == [0.0, 0.0, 0.0, 0.0] and world.cars[0].x == state.x
    assert not result.terminated


def test_team_bonus_once_every_car_finished_uncrashed():
    world = make_world()
    world.place_car(0, 167.0, 48.25, EAST, speed=5.0)
    world.place_car(1, 150.0, 48.25, EAST, speed=8.0)
    total, bonus_ticks, goal_ticks = np.zeros((4, 2)), [], {}
    while True:
        result = step(world, default=COAST)
        total += result.rewards
        bonus_ticks += [e.tick for e in kinds(result.events, "team_bonus")]
        goal_ticks.update({e.robot: e.tick for e in kinds(result.events, "goal")})
        if result.terminated:
            break
    t0, t1 = goal_ticks[0], goal_ticks[1]
    assert t0 < t1 and bonus_ticks == [t1]                     # paid once, when the last car arrives
    assert total[RewardTerm.PRIMARY, 0] == pytest.approx((6000 - t0) / 100 + (6000 - t1) / 100)
    assert total[RewardTerm.PRIMARY, 1] == pytest.approx(2 * (6000 - t1) / 100)
    assert total[RewardTerm.OBSERVATION].tolist() == [0.0, 0.0]
    with pytest.raises(RuntimeError, match="reset"):
        step(world)


def test_no_team_bonus_when_a_car_of_the_team_crashed():
    world = make_world()
    world.place_car(0, 60.0, 46.1, SOUTH, speed=2.0)           # about to leave the road
    world.place_car(1, 167.0, 48.25, EAST, speed=5.0)
    events = []
    while not world.done:
        events += step(world, default=COAST).events
    assert [e.robot for e in kinds(events, "crash")] == [0] and [e.robot for e in kinds(events, "goal")] == [1]
    assert kinds(events, "team_bonus") == []


def test_two_teams_earn_their_bonus_separately():
    world = make_world(n_cars=2, teams=2)
    assert [c.team for c in world.cars] == [1, -1]
    world.place_car(0, 167.0, 48.25, EAST, speed=5.0)           # team A: alone, arrives
    bonus = []
    for _ in range(10):
        bonus += kinds(step(world, {0: COAST}).events, "team_bonus")
    assert [e.team for e in bonus] == [1]


def test_leaving_the_road_is_a_crash_costing_two_per_m_s():
    world = make_world()
    world.place_car(0, 60.0, 46.1, SOUTH, speed=2.0)           # |d| 3.9 m; off road from 4.0 m
    result = step(world, {0: COAST})
    crash = kinds(result.events, "crash")
    assert [(e.robot, e.detail) for e in crash] == [(0, "off road")]
    assert result.rewards[RewardTerm.RULE, 0] == pytest.approx(-2 * 1.91, abs=0.01)   # −|v|/5, v = 19.1 px/s
    assert car_state(world, 0).status == ObjectStatus.FINISHED | ObjectStatus.CRASHED
    for _ in range(5):                                         # a crashed car brakes to a stop (high friction)
        step(world, {0: [1.0, 0.0, 0.0]})
    assert world.cars[0].abs_velocity < 1e-6 and world.cars[0].in_space


def test_driving_past_the_wrong_road_end_is_a_crash():
    world = make_world()
    world.place_car(0, 0.5, 51.75, WEST, speed=6.0)            # westbound at the west end; destination east
    events = []
    for _ in range(5):
        events += step(world, {0: COAST}).events
    assert [(e.robot, e.detail) for e in kinds(events, "crash")] == [(0, "past a road end")]


def test_hitting_a_building_is_a_crash_and_the_building_stops_the_car():
    world = make_world()
    # South of the horizontal road the building's north face is at y = 42.5; the car's nose 4 cm from it.
    world.place_car(0, 60.0, 42.5 + HALF_LENGTH + 0.04, SOUTH, speed=5.0)
    result = step(world, {0: COAST})
    assert [(e.robot, e.detail) for e in kinds(result.events, "crash")] == [(0, "building")]
    assert result.rewards[RewardTerm.RULE, 0] == pytest.approx(-10.0)    # |v| = 50 px/s → −10
    for _ in range(5):
        step(world)
    assert world.cars[0].y > 42.5 + HALF_LENGTH - 0.05                   # did not pass into it


def test_opposing_lane_costs_a_tenth_per_metre_and_is_reported_once():
    world = make_world()
    world.place_car(0, 20.0, 51.75, EAST, speed=4.0)           # eastbound in the westbound lane
    world.set_goal(0, 3)
    x0, rule, events = world.cars[0].x, 0.0, []
    for _ in range(10):
        result = step(world, {0: COAST})
        rule += result.rewards[RewardTerm.RULE, 0]
        events += result.events
    assert rule == pytest.approx(-0.1 * (world.cars[0].x - x0), rel=1e-6)
    assert [e.robot for e in kinds(events, "opposing_lane")] == [0]
    world.place_car(0, world.cars[0].x, 48.25, EAST, speed=4.0)          # back in its lane: no cost
    assert step(world, {0: COAST}).rewards[RewardTerm.RULE, 0] == 0.0


def test_progress_pays_a_fifth_per_metre_closer_and_costs_moving_away():
    world = make_world()
    world.place_car(0, 100.0, 48.25, EAST, speed=5.0)
    def distance():   # to the destination, the east road end (170, 50)
        return math.hypot(170.0 - world.cars[0].x, 50.0 - world.cars[0].y)
    d0, aux = distance(), 0.0
    for _ in range(10):
        aux += step(world, {0: COAST}).rewards[RewardTerm.AUXILIARY, 0]
    assert aux == pytest.approx(0.2 * (d0 - distance()), rel=1e-9)
    assert aux == pytest.approx(0.2 * 4.505, abs=0.01)        # 5 m/s coasting (−0.09 m/s per period) for 1 s
    world.set_goal(0, 2)                                       # now the west end: driving east is moving away
    assert step(world, {0: COAST}).rewards[RewardTerm.AUXILIARY, 0] < 0


def test_head_on_collision_both_crash_and_the_wrong_way_driver_pays_double():
    world = make_world()
    # Car 0 eastbound in its lane at 4 m/s; car 1 westbound in the same lane (its opposing lane) at 6 m/s.
    world.place_car(0, 60.0, 48.25, EAST, speed=4.0)
    world.place_car(1, 60.0 + 2 * HALF_LENGTH + 0.05, 48.25, WEST, speed=6.0)
    result = step(world, default=COAST)
    crashes = {e.robot: e.detail for e in kinds(result.events, "crash")}
    assert crashes == {0: "car 1", 1: "car 0"}
    assert result.rewards[RewardTerm.RULE, 0] == pytest.approx(-2 * 4.0)        # right lane: −|v|/5
    assert result.rewards[RewardTerm.RULE, 1] == pytest.approx(-2 * 2 * 6.0)    # opposing lane: twice
    assert all(car_state(world, i).status & ObjectStatus.CRASHED for i in (0, 1))
    assert result.terminated


def test_rear_end_collision_in_one_lane_costs_the_car_driving_into_the_other_double():
    world = make_world()
    world.place_car(0, 60.0, 48.25, EAST)                                       # standing in its lane
    world.place_car(1, 60.0 - 2 * HALF_LENGTH - 0.04, 48.25, EAST, speed=5.0)  # drives into it from behind
    result = step(world, {1: COAST})
    assert sorted(e.robot for e in kinds(result.events, "crash")) == [0, 1]
    assert result.rewards[RewardTerm.RULE, 0] == pytest.approx(0.0)            # standing: |v| = 0
    assert result.rewards[RewardTerm.RULE, 1] == pytest.approx(-2 * 2 * 5.0)


def test_pedestrian_hit_head_on_kills_and_crashes_the_car():
    world = make_world(pedestrians=1)
    world.place_car(0, 60.0, 48.25, EAST, speed=3.0)
    world.place_pedestrian(0, 60.0 + HALF_LENGTH + 0.5 + 0.02, 48.25)
    result = step(world, {0: COAST})
    assert [(e.robot, e.detail) for e in kinds(result.events, "pedestrian_hit")] == [(0, "pedestrian 2")]
    assert [(e.robot, e.detail) for e in kinds(result.events, "crash")] == [(0, "pedestrian")]
    assert result.rewards[RewardTerm.RULE, 0] == pytest.approx(-2 * 3.0)
    pedestrian = next(o for o in world.snapshot().objects if o.class_id == ObjectClass.PEDESTRIAN)
    assert pedestrian.status == ObjectStatus.CRASHED and (pedestrian.vx, pedestrian.vy) == (0.0, 0.0)


def test_pedestrian_walking_into_a_cars_side_dies_but_the_car_is_not_to_blame():
    world = make_world(pedestrians=1)
    world.place_car(0, 60.0, 48.25, EAST, speed=3.0)
    world.place_pedestrian(0, 60.3, 48.25 - 0.6 - 0.5 - 0.3, vx=0.0, vy=1.2)   # from the car's right side
    events, rule = [], 0.0
    for _ in range(3):
        result = step(world, {0: [0.3, 0.0, 0.0]})
        events += result.events
        rule += result.rewards[RewardTerm.RULE, 0]
    assert [e.robot for e in kinds(events, "pedestrian_hit")] == [0]
    assert kinds(events, "crash") == [] and rule == 0.0 and not world.cars[0].finished


def test_a_standing_car_does_not_hurt_a_pedestrian():
    world = make_world(pedestrians=1)
    world.place_car(0, 60.0, 48.25, EAST)
    world.place_pedestrian(0, 60.0, 46.5, vx=0.0, vy=1.0)       # walks across the standing car
    events = []
    for _ in range(30):
        events += step(world).events
    assert kinds(events, "pedestrian_hit") == [] and world.pedestrians.alive[0]
    assert world.pedestrians.bodies[0].position.y > 48.25 + 1.0


def test_crash_penalty_scales_with_speed():
    penalties = []
    for speed in (2.0, 8.0):
        world = make_world()
        world.place_car(0, 60.0, 42.5 + HALF_LENGTH + speed * 0.01 - 0.005, SOUTH, speed=speed)   # touches in tick 1
        penalties.append(step(world, {0: COAST}).rewards[RewardTerm.RULE, 0])
    assert penalties == pytest.approx([-4.0, -16.0])


def test_the_walls_keep_sliding_cars_inside_the_world():
    world = make_world()
    world.place_car(0, 165.0, 48.25, EAST, speed=20.0)          # reaches its destination fast, then slides
    world.place_car(1, 150.0, 48.25, EAST, speed=25.0)
    world.set_goal(1, 2)                                          # not its destination: crash past the end
    while not world.done:
        step(world, default=COAST)
    assert world.cars[1].crashed and world.cars[1].x < 170.0 + 10.0
