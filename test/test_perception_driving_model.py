"""Driving perception (docs/perception.md, "Driving"): geometry, the exact preset, the error model's statistics,
bad parameters. Expected values are written out from the documented formulas and the presets' numbers, never
computed by the code under test; tolerances are a few standard errors of the sample."""
from __future__ import annotations

import math
import re

import numpy as np
import pytest

from dynenv_ros.driving.config import DrivingConfig
from dynenv_ros.driving.vision import DrivingVision
from dynenv_ros.driving.world import DrivingWorld
from dynenv_ros.perception.driving_model import (LANE_CENTRE, ROAD_EDGE, DrivingPerceiver, DrivingScene,
                                                 DrivingState)
from dynenv_ros.perception.driving_params import driving_params_from_mapping, load_driving_preset

CAR, PEDESTRIAN, OBSTACLE, LANE, SELF = 20, 21, 22, 23, 24
DISTANT, PARTIAL, NEARBY = 1, 2, 4
SAME, OPPOSING, EDGE = 10, 11, 12
VIEW = 68.0                                   # m, the original's 680 px radius


def scene(cars, pedestrians=(), obstacles=(), buildings=(), lanes=(), lane_kind=None, teams=None):
    """cars: (x, y, yaw, half_length, half_width); the first car observes (every car does)."""
    cars = np.asarray(cars, float).reshape(-1, 5)
    n = len(cars)
    sc = DrivingScene(car_half_length=cars[:, 3], car_half_width=cars[:, 4],
                      car_team=np.asarray(teams if teams is not None else [1] * n, np.int8),
                      n_pedestrians=len(pedestrians), pedestrian_radius=0.5,
                      obstacle_xy=np.asarray(obstacles, float).reshape(-1, 2), obstacle_half=1.0,
                      buildings=np.asarray(buildings, float).reshape(-1, 5), lanes=np.asarray(lanes, float).reshape(-1, 4),
                      lane_kind=np.asarray(lane_kind if lane_kind is not None else [LANE_CENTRE] * len(lanes), int),
                      lane_width=3.5)
    ped = np.asarray(pedestrians, float).reshape(-1, 2)
    st = DrivingState(x=cars[:, 0], y=cars[:, 1], yaw=cars[:, 2], speed=np.full(n, 3.0), yaw_rate=np.full(n, 0.1),
                      present=np.ones(n, bool), crashed=np.zeros(n, bool), finished=np.zeros(n, bool),
                      goal_x=np.full(n, 100.0), goal_y=np.full(n, 50.0), pedestrian_x=ped[:, 0],
                      pedestrian_y=ped[:, 1], pedestrian_alive=np.ones(len(ped), bool))
    return sc, st


def perceive(preset, sc, st, seed=0, **overrides):
    params = load_driving_preset(preset, **overrides) if isinstance(preset, str) else preset
    return DrivingPerceiver(sc, params).perceive(st, np.random.default_rng(seed))


def to_frame(x, y, ox, oy, yaw):
    c, s = math.cos(yaw), math.sin(yaw)
    return c * (x - ox) + s * (y - oy), -s * (x - ox) + c * (y - oy)


def ids(rows, cls=None):
    rows = rows if cls is None else rows[rows["class_id"] == cls]
    return set(rows["true_id"].tolist())


# -- geometry ------------------------------------------------------------------------------------------------------
def test_none_is_exact_ground_truth_in_the_observer_frame_all_round():
    ox, oy, oyaw = 50.0, 40.0, 0.7
    cars = [(ox, oy, oyaw, 2.0, 1.0), (30.0, 35.0, -2.0, 1.5, 0.6), (60.0, 80.0, 1.0, 2.5, 0.8)]
    peds = [(45.0, 50.0), (58.0, 30.0)]
    obst = [(40.0, 60.0)]
    sc, st = scene(cars, peds, obst)
    out = perceive("none", sc, st)
    rows = out.of_view(0)
    assert rows["class_id"][0] == SELF                                   # the SELF row first
    gx, gy = to_frame(100.0, 50.0, ox, oy, oyaw)
    assert rows["x"][0] == pytest.approx(gx, abs=1e-4) and rows["y"][0] == pytest.approx(gy, abs=1e-4)
    assert (rows["line_start_x"][0], rows["line_start_y"][0]) == pytest.approx((3.0, 0.1))
    assert (rows["size_x"][0], rows["size_y"][0]) == pytest.approx((4.0, 2.0))
    objects = rows[1:]
    # every object within 68 m, in front and behind (bearings of all signs): 2 cars, 2 pedestrians, 1 obstacle
    assert ids(objects) == {1, 2, 3, 4, 5}
    expected = {1: (30.0, 35.0), 2: (60.0, 80.0), 3: peds[0], 4: peds[1], 5: obst[0]}
    for r in objects:
        x, y = to_frame(*expected[int(r["true_id"])], ox, oy, oyaw)
        assert (r["x"], r["y"]) == pytest.approx((x, y), abs=1e-4)
        assert r["confidence"] == 1.0 and r["team"] == (1 if r["class_id"] == CAR else 0)
    car1 = objects[objects["true_id"] == 1][0]
    assert car1["yaw"] == pytest.approx(math.remainder(-2.0 - oyaw, math.tau), abs=1e-5)
    assert (car1["size_x"], car1["size_y"]) == pytest.approx((3.0, 1.2))
    assert np.isnan(objects[objects["class_id"] == PEDESTRIAN]["yaw"]).all()
    bearings = np.arctan2(objects["y"], objects["x"])
    assert (np.abs(bearings) > math.pi / 2).any() and (np.abs(bearings) < math.pi / 2).any()
    d = np.hypot(objects["x"], objects["y"])
    assert (np.diff(d) >= 0).all()                                        # nearest first
    assert out.seen[0, 1:].all() and not out.seen[0, 0]


def test_range_cut_at_the_view_radius():
    sc, st = scene([(0, 0, 0, 2, 1)], pedestrians=[(VIEW - 0.05, 0.0), (0.0, -(VIEW + 0.05))],
                   obstacles=[(-40.0, 40.0), (-50.0, 50.0)])                 # 56.6 m and 70.7 m
    rows = perceive("none", sc, st).of_view(0)
    assert ids(rows[1:]) == {1, 3}


def test_a_rotated_building_hides_with_its_rotated_corners():
    # A thin wall 10 m x 1 m, centre (10, 0), turned 45°: it crosses the sight line to (14, −6) at (7, −3).
    # With its corners left unrotated (the original's bug) it would span |y| ≤ 0.5 there and hide nothing.
    wall = (10.0, 0.0, 5.0, 0.5, math.pi / 4)
    sc, st = scene([(0, 0, 0, 2, 1)], pedestrians=[(14.0, -6.0), (12.0, 4.0)], buildings=[wall])
    rows = perceive("none", sc, st).of_view(0)
    assert ids(rows[1:]) == {2}                                           # (12, 4): the wall lies beyond it
    sc, st = scene([(0, 0, 0, 2, 1)], pedestrians=[(14.0, -6.0)], buildings=[(10.0, 0.0, 5.0, 0.5, 0.0)])
    assert ids(perceive("none", sc, st).of_view(0)[1:]) == {1}            # the same wall unrotated hides nothing


def test_partly_hidden_is_partial_and_buildings_hide_every_class():
    block = (10.0, 0.0, 1.0, 1.0, 0.0)
    # a car at (20, 2): its centre's and right edge's sight lines pass the block's corner (9, 1), its left edge's not
    sc, st = scene([(0, 0, 0, 2, 1), (20.0, 2.0, 0.0, 2.0, 1.0), (20.0, 0.0, 0.0, 2.0, 1.0)],
                   obstacles=[(30.0, 0.0)], buildings=[block])
    rows = perceive("none", sc, st).of_view(0)[1:]
    assert ids(rows) == {1}                                               # car 2 and the obstacle wholly hidden
    assert rows[rows["true_id"] == 1]["sighting"][0] & PARTIAL


def test_pedestrians_hidden_by_cars_and_obstacles():
    sc, st = scene([(0, 0, 0, 2, 1), (10.0, 0.0, 0.0, 2.0, 1.0)],
                   pedestrians=[(20.0, 0.0), (20.0, 6.0), (0.0, -20.0)], obstacles=[(0.0, -10.0)])
    rows = perceive("none", sc, st).of_view(0)[1:]
    assert ids(rows, PEDESTRIAN) == {3}                                    # behind the car, behind the obstacle
    # the original's rule (none, dynenv): cars do not hide cars; realistic: a car hides the car behind it
    sc, st = scene([(0, 0, 0, 2, 1), (10.0, 0.0, 0.0, 2.5, 0.8), (20.0, 0.0, 0.0, 1.0, 0.5)])
    assert ids(perceive("none", sc, st).of_view(0)[1:]) == {1, 2}
    realistic = load_driving_preset("realistic", mode="none", noise_magnitude=0.0)
    assert ids(perceive(realistic, sc, st).of_view(0)[1:]) == {1}


def test_lanes_are_clipped_to_the_range_with_an_observer_frame_endpoint_order():
    lanes = [(-200.0, 3.0, 200.0, 3.0), (200.0, -3.0, -200.0, -3.0), (-200.0, 7.0, 200.0, 7.0),
             (5.0, -200.0, 5.0, 200.0)]
    kinds = [LANE_CENTRE, LANE_CENTRE, ROAD_EDGE, LANE_CENTRE]
    sc, st = scene([(10.0, 0.0, 0.0, 2, 1)], lanes=lanes, lane_kind=kinds)
    rows = perceive("none", sc, st).of_view(0)
    lane = rows[rows["class_id"] == LANE]
    assert len(lane) == 4
    by_id = {-2 - k: r for k, r in enumerate(lane[np.argsort(-lane["true_id"])])}
    half = math.sqrt(VIEW ** 2 - 9.0)
    first = by_id[-2]
    assert (first["x"], first["y"]) == pytest.approx((0.0, 3.0), abs=1e-4)     # the nearest point
    assert first["size_x"] == pytest.approx(2 * half, abs=1e-3) and first["size_y"] == pytest.approx(3.5)
    # equally far ends: the rear end first (a rule of the observer's frame, not of the map's segment direction)
    assert (first["line_start_x"], first["line_end_x"]) == pytest.approx((-half, half), abs=1e-3)
    assert by_id[-3]["line_start_x"] == pytest.approx(-half, abs=1e-3)
    assert first["subtype"] == SAME and by_id[-3]["subtype"] == OPPOSING and by_id[-4]["subtype"] == EDGE
    assert first["yaw"] == pytest.approx(0.0, abs=1e-6) and first["sighting"] & PARTIAL
    cross = by_id[-5]                                                     # x = 5 − 10 = −5 m, square to the car
    assert cross["x"] == pytest.approx(-5.0, abs=1e-4) and cross["yaw"] == pytest.approx(-math.pi / 2, abs=1e-6)
    assert cross["line_start_y"] < cross["line_end_y"]                    # a tie: the right end first
    # turned around, the car sees its own lane as opposing
    sc, st = scene([(10.0, 0.0, math.pi, 2, 1)], lanes=lanes, lane_kind=kinds)
    lane = perceive("none", sc, st).of_view(0)
    assert lane[lane["true_id"] == -2]["subtype"][0] == OPPOSING


def _situation():
    cars = [(20.0, 10.0, 0.4, 2.0, 1.0), (35.0, 18.0, 2.0, 1.5, 0.6), (10.0, 40.0, -1.0, 2.5, 0.8),
            (45.0, -5.0, 0.0, 1.0, 0.5)]
    peds = [(30.0, 12.0), (41.0, 20.0), (5.0, 5.0), (27.0, 30.0)]
    obst = [(15.0, 25.0), (32.0, 4.0)]
    buildings = [(25.0, 45.0, 8.0, 3.0, 0.3), (-5.0, 20.0, 4.0, 6.0, 0.0)]
    lanes = [(-60.0, 14.0, 90.0, 14.0), (90.0, 18.0, -60.0, 18.0), (-60.0, 21.0, 90.0, 21.0)]
    return cars, peds, obst, buildings, lanes


def _key(rows):
    r = rows[np.lexsort((rows["true_id"], rows["class_id"]))]
    return r


def test_a_moved_turned_or_mirrored_situation_gives_the_same_or_mirrored_reports():
    cars, peds, obst, buildings, lanes = _situation()
    kinds = [LANE_CENTRE, LANE_CENTRE, ROAD_EDGE]
    base = perceive("none", *scene(cars, peds, obst, buildings, lanes, kinds))

    def moved(x, y, yaw):        # a quarter turn about (3, −7) and a shift: obstacles stay axis-aligned
        return -(y + 7.0) + 3.0 + 100.0, (x - 3.0) - 7.0 + 40.0, yaw + math.pi / 2

    cars_m = [(*moved(x, y, yaw), hl, hw) for x, y, yaw, hl, hw in cars]
    peds_m = [moved(x, y, 0)[:2] for x, y in peds]
    obst_m = [moved(x, y, 0)[:2] for x, y in obst]
    bld_m = [(*moved(x, y, yaw), hx, hy) for x, y, hx, hy, yaw in buildings]
    bld_m = [(x, y, hx, hy, yaw) for x, y, yaw, hx, hy in bld_m]
    lanes_m = [(*moved(a, b, 0)[:2], *moved(c, d, 0)[:2]) for a, b, c, d in lanes]
    sc, st = scene(cars_m, peds_m, obst_m, bld_m, lanes_m, kinds)
    st.goal_x[:], st.goal_y[:] = moved(100.0, 50.0, 0)[:2]
    turned = perceive("none", sc, st)
    # mirrored about the map's x axis: y → −y, headings → −heading
    sc, st = scene([(x, -y, -yaw, hl, hw) for x, y, yaw, hl, hw in cars], [(x, -y) for x, y in peds],
                   [(x, -y) for x, y in obst], [(x, -y, hx, hy, -yaw) for x, y, hx, hy, yaw in buildings],
                   [(a, -b, c, -d) for a, b, c, d in lanes], kinds)
    st.goal_y[:], st.yaw_rate[:] = -50.0, -0.1
    mirrored = perceive("none", sc, st)
    assert len(base.detections) > 20
    for v in range(len(cars)):
        a, b, m = _key(base.of_view(v)), _key(turned.of_view(v)), _key(mirrored.of_view(v))
        assert len(a) == len(b) == len(m)
        for name in ("class_id", "true_id", "subtype", "sighting", "size_x"):
            assert (a[name] == b[name]).all() and (a[name] == m[name]).all(), name
        for name in ("x", "y", "yaw", "line_start_x", "line_start_y", "line_end_x", "line_end_y"):
            assert np.allclose(a[name], b[name], atol=2e-4, equal_nan=True), name
        for name, sign in (("x", 1), ("y", -1), ("yaw", -1), ("line_start_x", 1), ("line_start_y", -1),
                           ("line_end_x", 1), ("line_end_y", -1)):
            keep = ~((a["class_id"] == LANE) & (np.abs(np.abs(a["yaw"]) - math.pi / 2) < 1e-4))   # a line's yaw is mod π
            assert np.allclose(a[name][keep], sign * m[name][keep], atol=2e-4, equal_nan=True), name


# -- the error model -----------------------------------------------------------------------------------------------
def _ring(radius, count=60, observer_yaw=0.3):
    angles = np.arange(count) * 2 * math.pi / count
    return scene([(0, 0, observer_yaw, 2, 1)], obstacles=np.column_stack((radius * np.cos(angles),
                                                                           radius * np.sin(angles))))


def _collect(preset, sc, st, frames, seed=0, **overrides):
    perceiver = DrivingPerceiver(sc, load_driving_preset(preset, **overrides))
    rng = np.random.default_rng(seed)
    return [perceiver.perceive(st, rng) for _ in range(frames)]


def _rate_ok(count, total, p, sigmas=4.0):
    se = math.sqrt(p * (1 - p) / total)
    return abs(count / total - p) < sigmas * se + 1e-9, (count / total, p, se)


@pytest.mark.parametrize("preset, radius, distant", [("realistic", 20.0, False), ("realistic", 45.0, True),
                                                     ("dynenv", 20.0, False), ("dynenv", 45.0, True)])
def test_miss_and_confusion_rates_follow_the_documented_formula(preset, radius, distant):
    sc, st = _ring(radius)
    outs = _collect(preset, sc, st, 250, noise_magnitude=5.0)
    rho = 0.01 * 5.0
    mult = (0.25 + 3.75 * (radius / 68.0) ** 2) * (3.0 if distant else 1.0)    # obstacles: near 30 m / 34 m
    p_miss, p_confused = rho * mult, 0.5 * rho * mult                          # miss_scale 1, confusion 0.5
    total = 60 * len(outs)
    real = np.concatenate([o.detections[o.detections["true_id"] >= 1] for o in outs])
    ok, info = _rate_ok(total - len(real), total, p_miss)
    assert ok, info
    ok, info = _rate_ok(int((real["class_id"] == CAR).sum()), len(real), p_confused)
    assert ok, info
    # DISTANT from the report itself: beyond the reported class's near range (obstacle 30 / 34 m, car 40 / 34 m)
    near = {("realistic", OBSTACLE): 30.0, ("realistic", CAR): 40.0, ("dynenv", OBSTACLE): 34.0, ("dynenv", CAR): 34.0}
    reach = np.hypot(real["x"], real["y"])
    limit = np.array([near[(preset, int(c))] for c in real["class_id"]])
    assert (((real["sighting"] & DISTANT) > 0) == (reach > limit)).all()
    assert ((real["sighting"] & DISTANT) > 0).mean() > 0.95 if distant else ((real["sighting"] & DISTANT) == 0).all()


def test_false_positives_per_view_classes_and_distances():
    sc, st = scene([(0, 0, 0, 2, 1)])
    outs = _collect("realistic", sc, st, 3000, noise_magnitude=5.0)
    fp = np.concatenate([o.detections[o.detections["true_id"] == -1] for o in outs])
    # 10 trials per view, P = 0.01·5 each; 3 of the 6 class options are 'none'
    expected = 10 * 0.05 * 0.5
    se = math.sqrt(10 * 0.05 * 0.95 * 0.5 + 10 * 0.05 * 0.25) / math.sqrt(len(outs))   # binomial thinned: ≤ this
    assert abs(len(fp) / len(outs) - expected) < 4 * se, (len(fp) / len(outs), expected)
    for cls, reach in ((CAR, 68.0), (PEDESTRIAN, 50.0), (OBSTACLE, 60.0)):    # uniform up to the class's range
        d = np.hypot(fp["x"], fp["y"])[fp["class_id"] == cls]
        ok, info = _rate_ok(len(d), len(fp), 1 / 3)
        assert ok, info
        assert d.max() <= reach and abs(d.mean() - reach / 2) < 4 * reach / math.sqrt(12 * len(d))
    bearing = np.arctan2(fp["y"], fp["x"])
    assert (bearing < -math.pi / 2).mean() == pytest.approx(0.25, abs=4 * math.sqrt(3 / 16 / len(fp)))


def test_pedestrians_reported_next_to_nearby_cars():
    sc, st = scene([(0, 0, 0, 2, 1), (10.0, 0.0, 1.0, 2.0, 1.0)])
    outs = _collect("realistic", sc, st, 3000, seed=3, false_positives={"trials": 0})
    kept = sum(int(((o.of_view(0)["true_id"] == 1) & (o.of_view(0)["class_id"] == CAR)).any()) for o in outs)
    near = 0
    for o in outs:
        r = o.of_view(0)
        ped = r[(r["class_id"] == PEDESTRIAN) & (r["true_id"] == -1)]
        near += len(ped)
        for x, y in zip(ped["x"], ped["y"]):        # outside the car's outline, at most 2.5 + 0.5 + 1 m from it
            assert 1.0 + 0.5 - 0.3 <= math.hypot(x - 10.0, y) <= 2.0 + 1.0 + 0.5 + 1.0 + 0.3
    # P = 0.1·magnitude per car seen within 25 m, not DISTANT or PARTIAL (then hidden behind the car: dropped)
    assert 0.5 * 0.1 * kept - 4 * math.sqrt(0.1 * kept) < near <= 0.1 * kept + 4 * math.sqrt(0.1 * kept)


@pytest.mark.parametrize("preset", ["realistic", "dynenv"])
def test_position_error_at_a_distance(preset):
    sc, st = _ring(20.0, observer_yaw=0.0)
    outs = _collect(preset, sc, st, 150)
    rows = np.concatenate([o.detections[o.detections["true_id"] >= 1] for o in outs])
    angles = (rows["true_id"] - 1) * 2 * math.pi / 60
    tx, ty = 20.0 * np.cos(angles), 20.0 * np.sin(angles)
    if preset == "realistic":           # radial σ = 0.05 + 0.0002·20² = 0.13 m, bearing σ = 0.0087 rad
        radial = np.hypot(rows["x"], rows["y"]) - 20.0
        bearing = np.remainder(np.arctan2(rows["y"], rows["x"]) - angles + math.pi, 2 * math.pi) - math.pi
        for err, sigma in ((radial, 0.13), (bearing, 0.0087)):
            assert abs(err.std() / sigma - 1) < 4 / math.sqrt(2 * len(err)), (err.std(), sigma)
            assert abs(err.mean()) < 4 * sigma / math.sqrt(len(err))
    else:                               # ± 0.5·0.1·(0.25 + 3.75·(20/68)²) m per axis, uniform
        half = 0.5 * 0.1 * (0.25 + 3.75 * (20 / 68) ** 2)
        for err in (rows["x"] - tx, rows["y"] - ty):
            assert np.abs(err).max() <= half + 1e-5
            assert abs(err.std() - 2 * half / math.sqrt(12)) < 4 * 2 * half / math.sqrt(12) / math.sqrt(2 * len(err))


@pytest.mark.parametrize("preset, sigma", [("realistic", 0.05 + 0.0001 * 9.0),
                                           ("dynenv", 1.0 * (0.25 + 3.75 * (3 / 68) ** 2) / math.sqrt(12))])
def test_lane_offset_error(preset, sigma):
    sc, st = scene([(0.0, 0.0, 0.0, 2, 1)], lanes=[(-200.0, 3.0, 200.0, 3.0)])
    outs = _collect(preset, sc, st, 1500)
    lane = np.concatenate([o.detections[o.detections["class_id"] == LANE] for o in outs])
    sx, sy, ex, ey = (lane[k].astype(float) for k in ("line_start_x", "line_start_y", "line_end_x", "line_end_y"))
    offset = np.abs(sx * (ey - sy) - sy * (ex - sx)) / np.hypot(ex - sx, ey - sy) - 3.0   # distance to the line
    assert abs(offset.std() / sigma - 1) < 4 / math.sqrt(2 * len(offset)), (offset.std(), sigma)
    miss = 1 - len(lane) / len(outs)                          # P = 0.01·(0.25 + 3.75·(3/68)²)
    ok, info = _rate_ok(round(miss * len(outs)), len(outs), 0.01 * (0.25 + 3.75 * (3 / 68) ** 2))
    assert ok, info


def test_self_row_odometry_error():
    sc, st = scene([(0, 0, 0, 2, 1)])
    outs = _collect("realistic", sc, st, 2000)
    speed = np.array([o.ego[0, 0] for o in outs])
    goal = np.array([o.ego[0, 2] for o in outs])
    assert abs(speed.std() / 0.05 - 1) < 4 / math.sqrt(2 * len(speed))
    assert abs(goal.std() / 0.5 - 1) < 4 / math.sqrt(2 * len(goal))
    assert abs(speed.mean() - 3.0) < 4 * 0.05 / math.sqrt(len(speed))


def test_nearby_pedestrians_are_missed_twice_as_often_and_flagged():
    # pedestrians 1.8 m in front of obstacles on a 20 m ring (clear of their corners): NEARBY doubles the multiplier (miss_scale 1.5)
    angles = np.arange(40) * 2 * math.pi / 40
    obst = np.column_stack((20 * np.cos(angles), 20 * np.sin(angles)))
    peds = np.column_stack((18.2 * np.cos(angles), 18.2 * np.sin(angles)))     # 1.8 m in front of each
    sc, st = scene([(0, 0, 0, 2, 1)], pedestrians=peds, obstacles=obst)
    outs = _collect("realistic", sc, st, 300, noise_magnitude=5.0, false_positives={"trials": 0},
                    confusions=[])
    rows = np.concatenate([o.detections[(o.detections["class_id"] == PEDESTRIAN)] for o in outs])
    p = 0.05 * 1.5 * (0.25 + 3.75 * (18.2 / 68) ** 2) * 2.0
    ok, info = _rate_ok(40 * len(outs) - len(rows), 40 * len(outs), p)
    assert ok, info
    assert (rows["sighting"] & NEARBY).mean() > 0.99


# -- the adapter and the world -------------------------------------------------------------------------------------
def test_vision_over_the_world_is_seeded_and_none_sees_every_visible_object():
    outs = []
    for _ in range(2):
        world = DrivingWorld(DrivingConfig(n_cars=3), seed=4)
        vision = DrivingVision(world, "realistic")
        rows = []
        for _t in range(30):
            world.step(np.ones((3, 2), int) * [2, 1])
            rows.append(vision.perceive().detections.copy())
        outs.append(np.concatenate(rows))
    assert outs[0].tobytes() == outs[1].tobytes()
    world = DrivingWorld(DrivingConfig(n_cars=3), seed=4)
    vision = DrivingVision(world, "none")
    world.step(np.ones((3, 2), int))
    out = vision.perceive()
    snap = world.snapshot()
    assert len(out) == 3 and out.ego.shape == (3, 8)
    for v in range(3):
        rows = out.of_view(v)
        assert rows["class_id"][0] == SELF and (rows["class_id"][1:] != SELF).all()
        assert set(rows["true_id"][rows["true_id"] >= 0].tolist()) - {v} == set(np.flatnonzero(out.visible[v]))
        for r in rows[(rows["true_id"] >= 0) & (rows["class_id"] != SELF)]:
            obj = snap.objects[int(r["true_id"])]
            assert obj.id == r["true_id"] and obj.class_id == r["class_id"]
            car = snap.objects[v]
            x, y = to_frame(obj.x, obj.y, car.x, car.y, car.yaw)
            assert (r["x"], r["y"]) == pytest.approx((x, y), abs=1e-3)


# -- parameters ----------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("overrides, message", [
    ({"colour": 1}, "unknown driving perception setting"),
    ({"noise_magnitude": 7}, "noise_magnitude"),
    ({"mode": "fuzzy"}, "mode"),
    ({"view_range": -1.0}, "view_range"),
    ({"classes": {"car": {"near_range": 10, "max_range": 90}}}, "classes"),
    ({"false_positives": {"probability": -0.1}}, "false_positives.probability"),
    ({"false_positives": {"classes": ["car", "ball"]}}, "unknown class 'ball'"),
    ({"miss": {"base": 0.01, "wobble": 2}}, "miss: unknown setting"),
    ({"confusions": [{"source": "car", "target": "car", "probability": 0.5}]}, "confusions[0]"),
    ({"occlusion": {"cars_hide": ["lane"]}}, "occlusion.cars_hide"),
    ({"position": {"model": "gaussian"}}, "position.model"),
])
def test_bad_parameters_are_refused_by_name(overrides, message):
    with pytest.raises(ValueError, match=re.escape(message)):
        load_driving_preset("realistic", **overrides)


def test_unknown_preset_is_refused():
    with pytest.raises(ValueError, match="unknown driving perception preset"):
        load_driving_preset("perfect")
    with pytest.raises(ValueError, match="mapping"):
        driving_params_from_mapping(["realistic"])

