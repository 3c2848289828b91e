"""The driving world as a ScenarioWorld: seeding and determinism, snapshots, clocks, pedestrians and obstacles."""
import json
import math
import random
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from dynenv_ros.core.object_classes import ObjectClass, ObjectStatus
from dynenv_ros.driving.config import DrivingConfig
from dynenv_ros.driving.pedestrians import CROSS
from dynenv_ros.driving.roads import LanePosition
from dynenv_ros.driving.world import DrivingWorld
from dynenv_ros.sim.reward_terms import RewardTerm
from dynenv_ros.sim.scenario import PeriodResult, ScenarioWorld

REPO = Path(__file__).resolve().parent.parent


def run(world, periods, seed=7):
    """Random discrete actions from their own generator; (snapshots, rewards) of every period."""
    rng = np.random.default_rng(seed)
    snapshots, rewards = [], []
    for _ in range(periods):
        result = world.step(rng.integers(0, 3, size=(world.n_cars, 2)))
        snapshots.append(world.snapshot())
        rewards.append(result.rewards)
        if world.done:
            break
    return snapshots, np.array(rewards)


def test_same_seed_same_trajectory_and_no_global_random_state():
    np.random.seed(1)
    random.seed(1)
    a = DrivingWorld(DrivingConfig(n_cars=4), seed=42)
    snaps_a, rewards_a = run(a, 150)
    np.random.seed(2)
    random.seed(2)
    b = DrivingWorld(DrivingConfig(n_cars=4), seed=42)
    snaps_b, rewards_b = run(b, 150)
    assert snaps_a == snaps_b
    np.testing.assert_array_equal(rewards_a, rewards_b)
    assert any(o.vx for o in snaps_a[-1].objects if o.class_id == ObjectClass.PEDESTRIAN)   # something moved


def test_reset_with_a_seed_replays_a_fresh_world_and_other_seeds_differ():
    fresh = DrivingWorld(DrivingConfig(n_cars=3), seed=5)
    first = fresh.snapshot()
    snaps_fresh, _ = run(fresh, 40)
    used = DrivingWorld(DrivingConfig(n_cars=3), seed=99)
    run(used, 40)
    used.reset(seed=5)
    assert used.episode_id == 1 and used.tick == 0
    assert used.snapshot().objects == first.objects
    snaps_used, _ = run(used, 40)
    assert [s.objects for s in snaps_used] == [s.objects for s in snaps_fresh]
    used.reset()                                  # no seed: the generator goes on, a different episode
    assert used.snapshot().objects != first.objects
    assert DrivingWorld(DrivingConfig(n_cars=3), seed=6).snapshot().objects != first.objects


def test_the_world_meets_the_scenario_protocol():
    world = DrivingWorld(seed=0)
    protocol_members = ("scenario", "episode_id", "tick", "rng", "reset", "step", "snapshot")
    assert all(hasattr(world, name) for name in protocol_members)
    assert set(protocol_members) <= set(ScenarioWorld.__annotations__) | set(vars(ScenarioWorld))
    assert world.scenario == 1 and isinstance(world.rng, np.random.Generator)
    result = world.step([[2, 1], [2, 1]])
    assert isinstance(result, PeriodResult) and result.rewards.shape == (len(RewardTerm), 2)


def test_snapshot_lists_cars_pedestrians_and_obstacles_with_unique_ids():
    world = DrivingWorld(DrivingConfig(n_cars=3), seed=3)
    snap = world.snapshot()
    assert (snap.scenario, snap.tick, snap.game_time, snap.time_remaining) == (1, 0, 0.0, 60.0)
    assert snap.tick_period == pytest.approx(0.01)
    cars, peds, obstacles = (snap.of_class(c) for c in (ObjectClass.CAR, ObjectClass.PEDESTRIAN,
                                                        ObjectClass.OBSTACLE))
    assert [c.id for c in cars] == [0, 1, 2] and 10 <= len(peds) <= 20 and 10 <= len(obstacles) <= 20
    assert len(snap.objects) == len(cars) + len(peds) + len(obstacles)
    assert sorted(o.id for o in snap.objects) == list(range(len(snap.objects)))
    ends = {(87.5, 0.0), (87.5, 100.0), (0.0, 50.0), (170.0, 50.0)}
    for car in cars:
        assert (car.goal_x, car.goal_y) in ends and car.status == ObjectStatus.NONE and car.team == 1
        assert (car.size_x, car.size_y) in {(2.0, 1.0), (3.0, 1.2), (4.0, 1.4), (5.0, 1.6)}
    assert all(math.isnan(o.goal_x) for o in peds + obstacles)
    assert {(o.size_x, o.size_y) for o in peds} == {(1.0, 1.0)} and {(o.size_x, o.size_y) for o in obstacles} == \
        {(2.0, 2.0)}
    world.step([[1, 1]] * 3)
    assert world.snapshot().tick == 10 and world.snapshot().game_time == pytest.approx(0.1)


def test_cars_start_in_right_lanes_apart_and_never_head_for_their_own_road_end():
    for seed in range(25):
        world = DrivingWorld(DrivingConfig(n_cars=10), seed=seed)
        spots = {(round(c.x, 3), round(c.y, 3)) for c in world.cars}
        assert len(spots) == 10
        for car in world.cars:
            assert world.lane_position(car.index) == LanePosition.RIGHT_LANE
            assert car.goal != car.start_end
            assert world.map.nearest_end(car.x, car.y) == car.start_end


def test_obstacles_stand_on_walkways_never_on_the_road():
    for seed in range(10):
        world = DrivingWorld(seed=seed)
        for x, y in world.obstacles_xy:
            for dx in (-1.0, 1.0):          # every corner of the 2 m box
                for dy in (-1.0, 1.0):
                    assert not world.map.on_carriageway(x + dx, y + dy)
            assert world.map.classify(x, y, 0.0) == LanePosition.OFF_ROAD


def test_pedestrians_keep_to_walkways_cross_now_and_then_and_stay_in_the_map():
    config = DrivingConfig.from_mapping({"n_cars": 1, "pedestrians": {"count_min": 20, "count_max": 20,
                                                                       "cross_probability": 0.3}})
    world = DrivingWorld(config, seed=11)
    world.place_car(0, 5.0, 48.25, 0.0)
    peds, crossings = world.pedestrians, 0
    for _ in range(600):
        world.step([[1, 1]])
        crossings += int((peds.mode == CROSS).sum())
        for i, body in enumerate(peds.bodies):
            x, y = body.position
            assert world.map.inside(x, y)
            if world.map.on_carriageway(x, y):
                assert peds.mode[i] == CROSS, f"pedestrian {i} on the road without crossing"
    assert crossings > 0
    speeds = {round(b.velocity.length, 6) for b in peds.bodies}
    assert speeds <= {round(0.1 * k, 6) for k in range(0, 13)}            # base 3..6 px/s × 0..2


def test_episode_is_truncated_after_600_periods_and_frames_come_at_each_periods_end():
    world = DrivingWorld(DrivingConfig(n_cars=2), seed=1)
    frames = []
    result = None
    for period in range(600):
        result = world.step([[1, 1], [1, 1]], on_frame=lambda k: frames.append((k, world.tick)))
        if period < 599:
            assert not (result.truncated or result.terminated)
    assert result.truncated and not result.terminated and world.done
    assert frames[:3] == [(0, 10), (0, 20), (0, 30)] and len(frames) == 600
    assert world.snapshot().phase == 6 and world.snapshot().time_remaining == 0.0
    with pytest.raises(RuntimeError, match="reset"):
        world.step([[1, 1], [1, 1]])
    world.reset()
    assert not world.done and world.tick == 0 and world.snapshot().phase == 2


def test_two_frames_per_period_when_configured():
    config = DrivingConfig.from_mapping({"rates": {"physics_hz": 100.0, "vision_period_ticks": 5,
                                                   "motion_period_ticks": 10}})
    world = DrivingWorld(config, seed=0)
    frames = []
    world.step([[2, 1], [2, 1]], on_frame=lambda k: frames.append((k, world.tick)))
    assert frames == [(0, 5), (1, 10)]


def test_actions_are_checked_before_anything_moves():
    world = DrivingWorld(seed=0)
    before = world.snapshot()
    with pytest.raises(ValueError, match="car_1"):
        world.step([[2, 1], [2, 7]])
    with pytest.raises(ValueError, match="expected 2 actions"):
        world.step([[2, 1]])
    assert world.snapshot() == before


def test_sim_benchmark_runs_the_driving_world():
    command = [sys.executable, "-m", "benchmarks", "sim", "--scenario", "driving", "--cars", "3", "--steps", "20",
               "--repeat", "2", "--json"]
    result = subprocess.run(command, capture_output=True, text=True, timeout=120, cwd=REPO)
    assert result.returncode == 0, result.stderr
    figures = json.loads(result.stdout)
    # without --observation it times the whole step with realistic perception, and says so
    assert figures["scenario"] == "driving" and figures["cars"] == 3 and figures["observation"] == "partial"
    assert figures["perception"] == "realistic" and "[the default observation]" in figures["measures"]
    rate = figures["env_steps_per_s"]
    assert len(rate["runs"]) == 2 and 0 < rate["min"] <= rate["median"] <= rate["max"]
    assert figures["env_steps_per_cpu_s"]["min"] > 0 and len(figures["env_steps_per_cpu_s"]["runs"]) == 2
    # each run's derived rates are computed from its rate (printed to 0.1): within 1
    for ticks, steps in zip(figures["physics_ticks_per_s"]["runs"], rate["runs"]):
        assert abs(ticks - steps * 10) <= 1
    for frames, steps in zip(figures["car_frames_per_s"]["runs"], rate["runs"]):
        assert abs(frames - steps * 3) <= 1
    alone = subprocess.run(command + ["--observation", "none"], capture_output=True, text=True, timeout=120,
                           cwd=REPO)
    assert alone.returncode == 0, alone.stderr
    figures = json.loads(alone.stdout)
    assert figures["observation"] == "none" and "world alone" in figures["measures"]
    assert "default" not in figures["measures"] and "car_frames_per_s" not in figures
    perceived = subprocess.run(command + ["--observation", "partial", "--perception", "dynenv"], capture_output=True,
                               text=True, timeout=120, cwd=REPO)
    assert perceived.returncode == 0, perceived.stderr
    figures = json.loads(perceived.stdout)
    assert figures["observation"] == "partial" and figures["perception"] == "dynenv"
    refused = subprocess.run(command[:-1] + ["--observation", "padded"], capture_output=True, text=True,
                             timeout=120, cwd=REPO)
    assert refused.returncode == 2 and "none / full / partial" in refused.stderr
