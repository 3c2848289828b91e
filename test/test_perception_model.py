"""The perception error model, checked statistically: each rule of each preset shows up at the configured rate.

Tolerances are 5 binomial (or normal) standard errors, so a correct model fails about once in a few million runs
while a wrong factor of 1.5 fails every time.
"""
import math

import numpy as np
import pytest

from dynenv_ros.core.object_classes import ObjectClass, Sighting
from dynenv_ros.perception.model import Perceiver
from dynenv_ros.perception.params import from_mapping, load_preset, load_yaml
from dynenv_ros.perception.scene import SceneFrames, SceneObjects, Views

ROBOT, BALL, POST, CROSS = ObjectClass.ROBOT, ObjectClass.BALL, ObjectClass.GOALPOST, ObjectClass.PENALTY_CROSS
SIZE = {ROBOT: 0.2, BALL: 0.1, POST: 0.1, CROSS: 0.1}


def scene(objects, views=1, lines=()):
    """Observer = object 0, a team-A robot at the origin looking along +x; ``objects`` = (class, x, y, yaw, team, fallen)."""
    rows = [(ROBOT, 0.0, 0.0, 0.0, 1, False)] + list(objects)
    cls = np.array([r[0] for r in rows], np.uint8)
    obj = SceneObjects(class_id=cls, object_id=np.arange(len(rows), dtype=np.int32),
                       size_x=np.array([SIZE.get(c, 0.1) for c in cls]),
                       size_y=np.array([SIZE.get(c, 0.1) for c in cls]),
                       team=np.array([r[4] for r in rows], np.int8), subtype=np.zeros(len(rows), np.uint8),
                       occluder=cls == ROBOT, dynamic=np.isin(cls, (ROBOT, BALL)),
                       lines=np.asarray(lines, float).reshape(-1, 4))
    frames = SceneFrames(x=np.array([[r[1] for r in rows]]), y=np.array([[r[2] for r in rows]]),
                         yaw=np.array([[r[3] for r in rows]]), fallen=np.array([[r[5] for r in rows]]),
                         penalized=np.zeros((1, len(rows)), bool))
    v = Views(frame=np.zeros(views, int), observer=np.zeros(views, int), head_yaw=np.zeros(views))
    return obj, frames, v


def perceive(params, objects, views=1, seed=0, lines=()):
    obj, frames, v = scene(objects, views, lines)
    return Perceiver(obj, params).perceive(frames, v, np.random.default_rng(seed), np.ones(views, np.int8))


def _within(successes, trials, p, sigmas=5.0):
    se = math.sqrt(max(p * (1 - p), 1e-12) / trials)
    return abs(successes / trials - p) <= sigmas * se + 1e-9


def multiplier(params, cls, d, factor_name=None):
    c, m = params.classes[cls], params.miss
    factor = {"partial": m.partial_factor, "distant": m.distant_factor, "nearby": m.nearby_factor}.get(factor_name, 1)
    return (m.range_offset + m.range_slope * (d / c.near_range) ** 2) * factor


def realistic_miss(params, cls, d, factor_name=None):
    return min(1.0, params.rho * params.classes[cls].miss_scale * multiplier(params, cls, d, factor_name))


def truly_seen(params, cls, d, factor_name=None):
    """P(detected as its own class): not missed, then not confused (ball <-> penalty cross rules)."""
    p_confuse = sum(min(1.0, r.probability * params.rho * multiplier(params, cls, d, factor_name))
                    for r in params.confusions if r.source == cls and (not r.distant_only or factor_name == "distant"))
    return (1 - realistic_miss(params, cls, d, factor_name)) * (1 - min(1.0, p_confuse))


def _ball_rows(perception, ball_id=1):
    d = perception.detections
    return d[d["true_id"] == ball_id]


@pytest.mark.parametrize("preset,magnitude", [("realistic", 1.0), ("realistic", 3.0), ("dynenv", 2.0)])
@pytest.mark.parametrize("distance", [1.0, 2.5, 4.5, 5.5])
def test_miss_rate_grows_with_distance_as_configured(preset, magnitude, distance):
    params = load_preset(preset, noise_magnitude=magnitude)
    views = 20000
    result = perceive(params, [(BALL, distance, 0.0, np.nan, 0, False)], views)
    c = params.classes[BALL]
    expected_seen = 0.0 if distance > c.max_range else truly_seen(
        params, BALL, distance, "distant" if distance > c.near_range else None)
    seen = int(result.seen[:, 1].sum())
    assert _within(seen, views, expected_seen), (seen / views, expected_seen)


def test_random_mode_misses_at_a_fixed_rate_whatever_the_distance():
    params = load_preset("realistic", mode="random", noise_magnitude=4.0)
    for distance in (1.0, 5.0):
        result = perceive(params, [(BALL, distance, 0.0, np.nan, 0, False)], 20000)
        expected = 1 - params.rho * params.classes[BALL].miss_scale          # and no confusions in random mode
        assert _within(int(result.seen[:, 1].sum()), 20000, expected)


@pytest.mark.parametrize("magnitude", [1.0, 3.0])
def test_false_positives_per_frame_and_where_they_appear(magnitude):
    params = load_preset("realistic", noise_magnitude=magnitude)
    views = 20000
    result = perceive(params, [], views)
    fps = result.detections[result.detections["true_id"] == -1]
    fp = params.false_positives
    real_classes = sum(c != ObjectClass.UNKNOWN for c in fp.classes) / len(fp.classes)
    expected = fp.trials * fp.probability * magnitude * real_classes
    assert abs(len(fps) / views - expected) < 5 * math.sqrt(expected / views)
    distance, bearing = np.hypot(fps["x"], fps["y"]), np.arctan2(fps["y"], fps["x"])
    assert distance.max() <= fp.max_distance and np.abs(bearing).max() <= params.field_of_view / 2 + 1e-6
    assert set(np.unique(fps["class_id"])) == {int(c) for c in fp.classes if c != ObjectClass.UNKNOWN}


def test_balls_appear_at_the_feet_of_nearby_robots_and_sometimes_replace_them():
    params = load_preset("realistic", noise_magnitude=2.0)
    views = 20000
    result = perceive(params, [(ROBOT, 1.5, 0.0, math.pi, -1, False)], views)
    d = result.detections
    fp_balls = d[(d["true_id"] == -1) & (d["class_id"] == BALL) & (np.hypot(d["x"] - 1.5, d["y"]) < 0.5)]
    p_robot_seen = 1 - realistic_miss(params, ROBOT, 1.5)
    p_feet = params.false_positives.at_feet_probability * 2.0
    uniform_near = 0.01 * 2 * 10 / 6 * (1.0 / 6.0)   # uniform FPs that happen to land near the robot: bounded above
    assert _within(len(fp_balls), views, p_robot_seen * p_feet, sigmas=5) or \
        len(fp_balls) / views < p_robot_seen * p_feet + uniform_near
    assert len(fp_balls) / views > 0.7 * p_robot_seen * p_feet
    dropped = views - int(result.seen[:, 1].sum())
    expected_dropped = 1 - p_robot_seen * (1 - p_feet * params.false_positives.at_feet_robot_dropped * 2.0)
    assert _within(dropped, views, expected_dropped)


def test_balls_and_penalty_crosses_are_confused_at_the_configured_rate():
    params = load_preset("realistic", noise_magnitude=3.0)
    views, distance = 40000, 2.0
    result = perceive(params, [(BALL, distance, 0.0, np.nan, 0, False)], views)
    rows = _ball_rows(result)
    as_cross = int((rows["class_id"] == CROSS).sum())
    p_miss = realistic_miss(params, BALL, distance)
    c = params.classes[BALL]
    mult = params.miss.range_offset + params.miss.range_slope * (distance / c.near_range) ** 2
    p_confuse = 0.5 * params.rho * mult
    assert _within(as_cross, views, (1 - p_miss) * p_confuse)
    assert np.all(rows["true_class"] == BALL)
    # confused sightings are not "truly seen" (they do not earn the observation reward)
    assert int(result.seen[:, 1].sum()) == len(rows) - as_cross


def test_robots_look_like_goalposts_only_at_a_distance():
    params = load_preset("realistic", noise_magnitude=3.0)
    near = perceive(params, [(ROBOT, 2.0, 0.0, 0.0, -1, False)], 20000)
    assert not np.any(near.detections["class_id"][near.detections["true_id"] == 1] == POST)
    far = perceive(params, [(ROBOT, 5.0, 0.0, 0.0, -1, False)], 20000)
    rows = far.detections[far.detections["true_id"] == 1]
    as_post = int((rows["class_id"] == POST).sum())
    c, m = params.classes[ROBOT], params.miss
    mult = (m.range_offset + m.range_slope * (5.0 / c.near_range) ** 2) * m.distant_factor
    p_miss = min(1.0, params.rho * c.miss_scale * mult)
    assert _within(as_post, 20000, (1 - p_miss) * min(1.0, params.rho * mult))


@pytest.mark.parametrize("distance", [1.0, 3.0, 5.0])
def test_realistic_position_error_grows_with_the_square_of_distance(distance):
    params = load_preset("realistic", noise_magnitude=1.0)
    rows = _ball_rows(perceive(params, [(BALL, distance, 0.0, np.nan, 0, False)], 20000))
    rows = rows[rows["class_id"] == BALL]
    radial = np.hypot(rows["x"], rows["y"]) - distance
    bearing = np.arctan2(rows["y"], rows["x"])
    p = params.position
    sigma = p.radial_base + p.radial_per_m2 * distance ** 2
    n = len(rows)
    assert abs(radial.std() / sigma - 1) < 5 / math.sqrt(2 * n)
    assert abs(radial.mean()) < 5 * sigma / math.sqrt(n)
    assert abs(bearing.std() / p.bearing_std - 1) < 5 / math.sqrt(2 * n)
    assert sigma > 0.05 if distance >= 3 else True   # errors a real detector makes: decimetres at 3 m


def test_dynenv_position_error_is_uniform_and_below_a_centimetre():
    params = load_preset("dynenv", noise_magnitude=1.0)
    distance = 2.0
    rows = _ball_rows(perceive(params, [(BALL, distance, 0.0, np.nan, 0, False)], 20000))
    err = rows["x"] - distance
    c, m = params.classes[BALL], params.miss
    mult = m.range_offset + m.range_slope * (distance / c.near_range) ** 2
    bound = 0.5 * params.position.uniform_scale * mult
    assert np.abs(err).max() <= bound + 1e-6 and bound < 0.01
    assert abs(err.std() - bound / math.sqrt(3)) < 0.05 * bound


def test_a_robot_on_the_line_of_sight_hides_the_ball_even_without_noise():
    params = load_preset("none")
    hidden = perceive(params, [(ROBOT, 1.0, 0.0, 0.0, -1, False), (BALL, 2.0, 0.05, np.nan, 0, False)])
    assert hidden.visible[0].tolist() == [False, True, False]
    beside = perceive(params, [(ROBOT, 1.0, 0.0, 0.0, -1, False), (BALL, 2.0, 0.6, np.nan, 0, False)])
    assert beside.visible[0].tolist() == [False, True, True]
    in_front = perceive(params, [(ROBOT, 2.0, 0.0, 0.0, -1, False), (BALL, 1.0, 0.0, np.nan, 0, False)])
    assert in_front.visible[0].tolist() == [False, True, True]


def test_field_of_view_edge_is_flagged_partial_and_beyond_it_nothing_is_seen():
    params = load_preset("none")
    half = params.field_of_view / 2
    r = params.classes[BALL].visibility_radius
    d = 2.0
    reach = math.asin(r / d)
    at = lambda angle: perceive(params, [(BALL, d * math.cos(angle), d * math.sin(angle), np.nan, 0, False)])
    inside, edge, outside = at(half - 2 * reach), at(half), at(half + 2 * reach)
    assert inside.of_view(0)["sighting"][0] & Sighting.PARTIAL == 0
    assert edge.of_view(0)["sighting"][0] & Sighting.PARTIAL
    assert len(outside.of_view(0)) == 0


def test_distant_and_nearby_flags():
    params = load_preset("none")
    near_range = params.classes[BALL].near_range
    rows = perceive(params, [(BALL, near_range + 0.5, 0.0, np.nan, 0, False)]).of_view(0)
    assert rows["sighting"][0] & Sighting.DISTANT
    rows = perceive(params, [(BALL, 1.5, 0.3, np.nan, 0, False), (ROBOT, 1.5, 0.55, 0.0, -1, False)]).of_view(0)
    assert rows[rows["class_id"] == BALL]["sighting"][0] & Sighting.NEARBY


def test_nearby_objects_are_missed_twice_as_often():
    params = load_preset("realistic", noise_magnitude=3.0)
    result = perceive(params, [(BALL, 1.5, 0.0, np.nan, 0, False), (ROBOT, 1.5, 0.3, 0.0, -1, False)], 20000)
    expected = truly_seen(params, BALL, 1.5, "nearby")
    assert _within(int(result.seen[:, 1].sum()), 20000, expected)


def test_noise_magnitude_zero_reports_exactly_what_is_visible():
    params = load_preset("realistic", noise_magnitude=0.0)
    objects = [(BALL, 2.0, 0.3, np.nan, 0, False), (ROBOT, 3.0, -0.8, 1.0, -1, True), (POST, 4.0, 1.0, np.nan, 0, False)]
    result = perceive(params, objects, 500)
    assert len(result.detections) == 500 * 3 and result.seen[:, 1:].all()
    rows = result.of_view(0)
    by_id = {int(r["true_id"]): r for r in rows}
    for i, (cls, x, y, yaw, team, fallen) in enumerate(objects, start=1):
        assert by_id[i]["class_id"] == cls and by_id[i]["x"] == pytest.approx(x) and by_id[i]["y"] == pytest.approx(y)
    robot = by_id[2]
    assert robot["yaw"] == pytest.approx(1.0) and robot["team"] == -1 and robot["fallen"]


def test_same_seed_same_detections_other_seed_other_detections():
    params = load_preset("realistic", noise_magnitude=2.0)
    objects = [(BALL, 2.0, 0.3, np.nan, 0, False), (ROBOT, 3.0, -0.8, 1.0, -1, False)]
    a, b, c = (perceive(params, objects, 200, seed=s) for s in (5, 5, 6))
    assert a.detections.tobytes() == b.detections.tobytes()
    assert a.detections.tobytes() != c.detections.tobytes()


def test_detections_do_not_depend_on_where_the_observer_stands_or_faces():
    """No absolute heading or position leaks into a detection (DynEnv leaked a compass, facts §12.3)."""
    params = load_preset("realistic", noise_magnitude=2.0)
    objects = [(BALL, 2.0, 0.3, np.nan, 0, False), (ROBOT, 3.0, -0.8, 1.0, -1, False)]
    base = perceive(params, objects, 100, seed=3)
    angle, shift = 2.1, np.array([1.5, -2.0])
    c, s = math.cos(angle), math.sin(angle)
    moved = [(cls, c * x - s * y + shift[0], s * x + c * y + shift[1], yaw + angle if np.isfinite(yaw) else yaw,
              team, fallen) for cls, x, y, yaw, team, fallen in objects]
    obj, frames, views = scene(moved, 100)
    frames.x[0, 0], frames.y[0, 0], frames.yaw[0, 0] = shift[0], shift[1], angle
    other = Perceiver(obj, params).perceive(frames, views, np.random.default_rng(3), np.ones(100, np.int8))
    for field in ("class_id", "team", "fallen", "sighting", "true_id"):
        np.testing.assert_array_equal(base.detections[field], other.detections[field])
    for field in ("x", "y", "yaw", "size_x"):
        np.testing.assert_allclose(base.detections[field], other.detections[field], atol=2e-4)


def test_the_observed_robots_own_state_is_reported_not_the_observers():
    params = load_preset("none")
    obj, frames, views = scene([(ROBOT, 2.0, 0.0, 0.0, 1, False)])
    frames.fallen[0, 0] = True                      # the observer is fallen, the observed robot is not
    rows = Perceiver(obj, params).perceive(frames, views, np.random.default_rng(0), np.ones(1, np.int8)).of_view(0)
    assert not rows["fallen"][0] and rows["team"][0] == 1


def test_a_line_is_clipped_to_the_view_and_reported_by_its_closest_point():
    params = load_preset("none")
    rows = perceive(params, [], lines=[(2.0, -10.0, 2.0, 10.0)]).of_view(0)
    assert len(rows) == 1 and rows["class_id"][0] == ObjectClass.FIELD_LINE
    half = params.field_of_view / 2
    ends = sorted([(rows["line_start_x"][0], rows["line_start_y"][0]), (rows["line_end_x"][0], rows["line_end_y"][0])],
                  key=lambda p: p[1])
    assert ends[0] == pytest.approx((2.0, -2.0 * math.tan(half)), abs=1e-5)
    assert ends[1] == pytest.approx((2.0, 2.0 * math.tan(half)), abs=1e-5)
    assert (rows["x"][0], rows["y"][0]) == pytest.approx((2.0, 0.0), abs=1e-5)
    assert abs(rows["yaw"][0]) == pytest.approx(math.pi / 2, abs=1e-5)
    assert rows["sighting"][0] & Sighting.PARTIAL
    assert len(perceive(params, [], lines=[(-2.0, -10.0, -2.0, 10.0)]).of_view(0)) == 0   # behind the camera


@pytest.mark.parametrize("values,message", [
    ({"mode": "sloppy"}, "mode"), ({"noise_magnitude": 6}, "noise_magnitude"), ({"colour": 1}, "unknown"),
    ({"classes": {"dragon": {"near_range": 1.0, "max_range": 2.0}}}, "unknown class"),
    ({"miss": {"base": -0.1}}, "base"), ({"miss": {"basis": 0.1}}, "unknown setting"),
    ({"field_of_view": 4.0}, "field_of_view"), ({"confusions": [{"source": "ball", "target": "kite",
                                                                 "probability": 1}]}, "unknown class")])
def test_bad_parameters_are_refused_by_name(values, message):
    base = {"classes": {n: {"near_range": 1.0, "max_range": 2.0} for n in (
        "ball", "robot", "goalpost", "penalty_cross", "line_crossing", "field_line", "center_circle")}}
    with pytest.raises(ValueError, match=message):
        from_mapping({**base, **values})


def test_a_corrupt_or_unknown_preset_file_is_refused_with_its_path(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text("perception: [unclosed\n")
    with pytest.raises(ValueError, match="bad.yaml"):
        load_yaml(bad)
    bad.write_text("something_else: 1\n")
    with pytest.raises(ValueError, match="top-level 'perception'"):
        load_yaml(bad)
    with pytest.raises(ValueError, match="unknown perception preset"):
        load_preset("perfect")
