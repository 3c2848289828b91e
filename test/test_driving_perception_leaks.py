"""No feature of a false or confused driving report gives it away (docs/perception.md, "Driving").

Reports of random driving (4 cars, realistic preset at noise magnitude 3 for enough false reports) are labelled
false (no object behind them, or the wrong class) or correct. Two logistic regressions, fitted on even views and
scored on odd ones: geometry alone (per class: distance, bearing, the distance to the nearest car or obstacle
report of the frame — rule 4 of the paper puts false pedestrians there on purpose) and geometry plus every other
feature but the confidence (heading, size, team, subtype, sighting bits). The chance level is the geometry's held-out
AUC (docs/perception.md records it); the extra features must not raise it beyond 3 bootstrap standard errors.

Every expectation here is computed independently of ``perception.audit`` (test/leak_reference.py, shared with the
soccer leak test: labels, brute-force nearest distances, AUCs by counting pairs, scipy's logistic fits), and
``driving_leak_check`` (the tool that prints docs/perception.md's figures) must agree with them.
"""
from __future__ import annotations

import math

import numpy as np
import pytest
from leak_reference import false_mask, held_out_comparison, nearest_report, pair_auc, standardised

from dynenv_ros.driving.config import DrivingConfig
from dynenv_ros.driving.vision import DrivingVision
from dynenv_ros.driving.world import DrivingWorld
from dynenv_ros.perception.audit import driving_leak_check
from dynenv_ros.perception.detections import FEATURE_COLUMNS, as_features
from dynenv_ros.perception.driving_params import load_driving_preset

CAR, PEDESTRIAN, OBSTACLE = 20, 21, 22
POINT = (CAR, PEDESTRIAN, OBSTACLE)
DISTANT, NEARBY = 1, 4
NEAR_RANGE = {CAR: 40.0, PEDESTRIAN: 25.0, OBSTACLE: 30.0}     # driving_realistic.yaml
OTHER = ("cos_yaw", "sin_yaw", "size_x", "size_y", "team", "subtype", "distant", "partial", "nearby")


@pytest.fixture(scope="module")
def reports():
    world = DrivingWorld(DrivingConfig(n_cars=4), seed=21)
    vision = DrivingVision(world, load_driving_preset("realistic", noise_magnitude=3.0),
                           rng=np.random.default_rng(22))
    rng = np.random.default_rng(23)
    rows, views, base = [], [], 0
    for _ in range(1500):
        if world.done:
            world.reset()
            vision.reset()
        world.step(rng.integers(0, 3, (4, 2)))
        out = vision.perceive()
        rows.append(out.detections)
        views.append(base + np.repeat(np.arange(len(out)), np.diff(out.offsets)))
        base += len(out)
    rows, views = np.concatenate(rows), np.concatenate(views)
    point = np.isin(rows["class_id"], POINT)
    return rows[point], views[point]


def _nearest_crowd(rows, views):
    """Distance to the nearest other car or obstacle report of the same view (inf if none)."""
    return nearest_report(rows, views, (CAR, OBSTACLE))


def _design(rows, near, extra):
    """Per class: distance (/68 m) and its square and cube, cos and sin of the bearing and cos of twice it, the
    distance n to the nearest car or obstacle report (capped at 10 m, /10), n², n < 2 m and n < 4 m; then the
    ``extra`` features; standardised, with an intercept."""
    f = as_features(rows)
    d = np.hypot(rows["x"], rows["y"]).astype(float) / 68.0
    b = np.arctan2(rows["y"], rows["x"]).astype(float)
    n = np.minimum(near, 10.0) / 10.0
    cols = []
    for cls in POINT:
        ind = (rows["class_id"] == cls).astype(float)
        geometry = [np.ones(len(rows)), d, d ** 2, d ** 3, np.cos(b), np.sin(b), np.cos(2 * b), n, n ** 2,
                    near < 2.0, near < 4.0]
        cols += [ind * g for g in geometry]
        cols += [ind * f[:, FEATURE_COLUMNS.index(name)] for name in extra]
    return standardised(cols)


def test_no_feature_but_the_confidence_adds_to_what_the_geometry_says(reports):
    rows, views = reports
    label = false_mask(rows)
    assert label.sum() > 1000, label.sum()
    near, train = _nearest_crowd(rows, views), views % 2 == 0           # whole frames on one side
    geometry, everything, se = held_out_comparison(*(_design(rows, near, extra) for extra in ((), OTHER)), label,
                                                   train)
    assert 0.55 < geometry < 0.98, geometry              # the chance level the geometry gives (documented)
    assert everything - geometry < 3 * se + 0.002, (geometry, everything, se)
    # The audit tool finds the same.
    check = driving_leak_check(rows, views, OTHER)
    assert (check.false_reports, check.reports) == (label.sum(), len(rows))
    assert check.geometry_auc == pytest.approx(geometry, abs=1e-3), (check.geometry_auc, geometry)
    assert check.extended_auc == pytest.approx(everything, abs=1e-3), (check.extended_auc, everything)
    assert check.difference_se == pytest.approx(se, abs=1e-3), (check.difference_se, se)


def test_sighting_bits_follow_the_report_for_real_and_false(reports):
    rows, views = reports
    d = np.hypot(rows["x"], rows["y"]).astype(float)
    near = np.array([NEAR_RANGE[int(c)] for c in rows["class_id"]])
    assert (((rows["sighting"] & DISTANT) > 0) == (d > near)).all()
    ped = rows["class_id"] == PEDESTRIAN
    nearby = _nearest_crowd(rows, views) < 2.0
    assert (((rows["sighting"][ped] & NEARBY) > 0) == nearby[ped]).all()
    assert not (rows["sighting"][~ped] & NEARBY).any()


def test_made_up_cars_and_obstacles_look_like_real_ones(reports):
    rows, _ = reports
    label = false_mask(rows)
    for cls in (CAR, OBSTACLE, PEDESTRIAN):
        of = rows["class_id"] == cls
        fake, real = rows["size_x"][of & label].astype(float), rows["size_x"][of & ~label].astype(float)
        assert len(fake) > 30, (cls, len(fake))
        se = math.sqrt(fake.var() / len(fake) + real.var() / len(real))
        assert abs(fake.mean() - real.mean()) < 4 * se + 1e-6, (cls, fake.mean(), real.mean())
    cars = rows["class_id"] == CAR
    assert np.isfinite(rows["yaw"][cars]).all() and np.isnan(rows["yaw"][~cars]).all()
    assert (rows["team"][cars] == 1).all() and (rows["team"][~cars] == 0).all()


def test_confidence_ranks_as_d_prime_allows_and_is_calibrated(reports):
    rows, _ = reports
    label = false_mask(rows)
    expected = 0.5 * (1 + math.erf(1.5 / 2))                 # Φ(d'/√2) with d' = 1.5: 0.856
    of = rows["class_id"] == CAR
    measured = pair_auc(-rows["confidence"][of].astype(float), label[of])
    assert abs(measured - expected) < 0.05, measured


def test_reports_of_a_frame_come_nearest_first(reports):
    rows, views = reports
    d = np.hypot(rows["x"], rows["y"])
    same = views[1:] == views[:-1]
    assert (d[1:][same] >= d[:-1][same] - 1e-5).all()
