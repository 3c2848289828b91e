"""Perception geometry: occlusion by each preset's rule, sighting bits and row order from the reports, what made-up
reports look like, confidence, and that no absolute pose leaks (rigid motions, mirror images, field lines included).

Expected values are written out here from the documented rules and numbers (docs/perception.md; the
original's in docs/original.md §2.7, §5.1, §12.3; the preset YAML where only it states a number); the documented
numbers themselves are the literal tables of test_perception_model.py.
"""
import math
from typing import NamedTuple

import numpy as np
import pytest

from dynenv_ros.core.object_classes import ObjectClass, Sighting, Subtype
from dynenv_ros.perception.model import Perceiver
from dynenv_ros.perception.params import load_preset
from dynenv_ros.perception.scene import SceneFrames, SceneObjects, Views
from test_perception_model import CLASSES, HALF_FOV, RADIUS, SIGMAS, assert_normal, assert_rate, perceive_in_chunks

ROBOT, BALL, POST, CROSS = ObjectClass.ROBOT, ObjectClass.BALL, ObjectClass.GOALPOST, ObjectClass.PENALTY_CROSS
CROSSING, LINE, CIRCLE = ObjectClass.LINE_CROSSING, ObjectClass.FIELD_LINE, ObjectClass.CENTER_CIRCLE
# Sizes unlike the model's nominal ones, so that a made-up report's size shows whether it is its class's size in
# the scene (docs "Made-up reports look like real ones of their class").
SIZE = {ROBOT: 0.25, BALL: 0.12, POST: 0.11, CROSS: 0.13, CROSSING: 0.14, CIRCLE: 1.5}
NEARBY_DISTANCE = 0.35     # docs "Crowding ... nearby_distance (0.35 m)", "NEARBY when another reported ball or robot"
# Occlusion (docs "Geometry", "Occlusion, two models"; docs table "occlusion | band, 0.35 m | cone, 0.15 m"):
# realistic 'cone', 0.15 m — hidden when farther and within asin(occluder_radius / d_robot) of the robot's bearing;
# DynEnv 'band', 0.35 m — a robot in the field of view hides what is farther, ahead along its sight line and within
# 0.35 m of that line (docs/original.md §2.7: "occluded if b lies within R of the line of sight to a and a is the
# closer one", R = 35 px, "A robot inside the field of view occludes").
CONE_RADIUS, BAND_RADIUS = 0.15, 0.35


class Thing(NamedTuple):
    cls: int
    x: float
    y: float
    yaw: float = math.nan
    team: int = 0
    fallen: bool = False
    penalized: bool = False
    subtype: int = 0


OBSERVER = Thing(ROBOT, 0.0, 0.0, 0.0, 1)


def build(things, lines=(), head_yaw=(0.0,), xs=None, ys=None):
    """Scene of ``things`` (things[0] observes). One frame seen with each head yaw, or with ``xs``/``ys`` (F, N)
    one frame per layout, each seen once."""
    cls = np.array([t.cls for t in things], np.uint8)
    n = len(things)
    size = np.array([SIZE[c] for c in cls])
    obj = SceneObjects(class_id=cls, object_id=np.arange(n, dtype=np.int32), size_x=size, size_y=size.copy(),
                       team=np.array([t.team for t in things], np.int8),
                       subtype=np.array([t.subtype for t in things], np.uint8), occluder=cls == ROBOT,
                       dynamic=np.isin(cls, (ROBOT, BALL)), lines=np.asarray(lines, float).reshape(-1, 4))
    if xs is None:
        xs, ys = np.array([[t.x for t in things]]), np.array([[t.y for t in things]])
        views = Views(frame=np.zeros(len(head_yaw), int), observer=np.zeros(len(head_yaw), int),
                      head_yaw=np.asarray(head_yaw, float))
    else:
        views = Views(frame=np.arange(len(xs)), observer=np.zeros(len(xs), int), head_yaw=np.zeros(len(xs)))
    f = len(xs)
    frames = SceneFrames(x=np.asarray(xs, float), y=np.asarray(ys, float),
                         yaw=np.tile([t.yaw for t in things], (f, 1)).astype(float),
                         fallen=np.tile([t.fallen for t in things], (f, 1)),
                         penalized=np.tile([t.penalized for t in things], (f, 1)))
    return obj, frames, views


def run(params, things, lines=(), head_yaw=(0.0,), seed=0, xs=None, ys=None, observer_team=1):
    obj, frames, views = build(things, lines, head_yaw, xs, ys)
    return perceive_in_chunks(Perceiver(obj, params), frames, views, np.random.default_rng(seed),
                              np.full(len(views), observer_team, np.int8))


def view_of_rows(perception):
    return np.repeat(np.arange(len(perception)), np.diff(perception.offsets))


# ---- occlusion: each preset's rule, written out ---------------------------------------------------------------------
def cone_hides(ox, oy, bx, by):
    """Realistic: the object is farther than the robot (in front of the observer) and its bearing is within the
    robot's angular half-width asin(0.15 / d_robot) of the robot's bearing."""
    d_o, d_b = np.hypot(ox, oy), np.hypot(bx, by)
    gap = np.abs(np.angle(np.exp(1j * (np.arctan2(by, bx) - np.arctan2(oy, ox)))))
    half_width = np.arcsin(np.minimum(1, CONE_RADIUS / d_o))
    return (np.abs(np.arctan2(oy, ox)) < math.pi / 2) & (d_b > d_o) & (gap < half_width)


def band_hides(ox, oy, bx, by):
    """DynEnv: the robot is in the field of view (its visibility radius 0.175 m, docs/original.md §2.7 "robot 17.5"),
    the object is farther, ahead along the robot's sight line and within 0.35 m of that line."""
    d_o, d_b = np.hypot(ox, oy), np.hypot(bx, by)
    in_view = np.abs(np.arctan2(oy, ox)) <= HALF_FOV + np.arcsin(np.minimum(1, 0.175 / d_o))
    along = (ox * bx + oy * by) / d_o
    across = np.abs(ox * by - oy * bx) / d_o
    return in_view & (d_b > d_o) & (along > 0) & (across < BAND_RADIUS)


def occlusion_case(preset, occluder, balls):
    """Each ball position (B, 2) in its own frame, with the occluding robot at ``occluder`` (one per frame or (B, 2)),
    through the preset's geometry and occlusion without noise (mode none): the ball's ``visible`` per frame."""
    occluder = np.broadcast_to(np.asarray(occluder, float), np.shape(balls))
    balls = np.asarray(balls, float)
    xs = np.column_stack((np.zeros(len(balls)), occluder[:, 0], balls[:, 0]))
    ys = np.column_stack((np.zeros(len(balls)), occluder[:, 1], balls[:, 1]))
    things = [OBSERVER, Thing(ROBOT, 0, 0, 0.0, -1), Thing(BALL, 0, 0)]
    result = run(load_preset(preset, mode="none"), things, xs=xs, ys=ys)
    reported = np.zeros(len(balls), bool)
    d = result.detections
    reported[view_of_rows(result)[d["true_id"] == 2]] = True
    np.testing.assert_array_equal(reported, result.visible[:, 2])        # mode none reports all that is visible
    return result.visible[:, 2]


@pytest.mark.parametrize("preset", ["realistic", "dynenv"])
def test_a_robot_hides_what_is_behind_it_by_the_presets_rule(preset):
    """Robot 2 m straight ahead, ball 4 m ahead at lateral offsets y (a grid that avoids the boundaries): the cone
    hides iff |atan2(y, 4)| < asin(0.15 / 2), i.e. |y| < 0.301 m; the band iff |y| < 0.35 m (distance from the
    sight line)."""
    y = (np.arange(-120, 120) + 0.5) * 0.005
    visible = occlusion_case(preset, (2.0, 0.0), np.column_stack((np.full_like(y, 4.0), y)))
    if preset == "realistic":
        hidden = np.abs(np.arctan2(y, 4.0)) < math.asin(CONE_RADIUS / 2.0)
        assert hidden.sum() == 120                  # |y| < 0.3008: the 60 grid points either side
    else:
        hidden = np.abs(y) < BAND_RADIUS
        assert hidden.sum() == 140
    np.testing.assert_array_equal(visible, ~hidden)


@pytest.mark.parametrize("preset,rule", [("realistic", cone_hides), ("dynenv", band_hides)])
def test_occlusion_matches_the_rule_on_random_layouts(preset, rule):
    """4000 random layouts against the rule written out above: occluder within ±80° in front, ball within ±45° and
    5.5 m; a third of the balls near the occluder's sight line, a third with the occluder just outside the view and
    the ball just inside it on the same side."""
    rng = np.random.default_rng(11)
    n = 4000
    group = rng.integers(0, 3, n)
    side = np.where(rng.random(n) < 0.5, -1.0, 1.0)
    d_o = np.where(group == 2, rng.uniform(0.6, 1.5, n), rng.uniform(0.4, 4.5, n))
    b_o = np.where(group == 2, side * rng.uniform(0.85, 1.1, n), rng.uniform(-1.4, 1.4, n))
    occ = np.column_stack((d_o * np.cos(b_o), d_o * np.sin(b_o)))
    d_b = np.where(group == 2, d_o + rng.uniform(0.0, 1.0, n), rng.uniform(0.3, 5.5, n))
    b_b = np.where(group == 2, side * rng.uniform(0.65, 0.8, n), rng.uniform(-0.8, 0.8, n))
    balls = np.column_stack((d_b * np.cos(b_b), d_b * np.sin(b_b)))
    t, s = rng.uniform(-1.0, 2.5, n), rng.uniform(-0.6, 0.6, n)     # along the sight line past the robot, aside
    u = occ / d_o[:, None]
    balls[group == 1] = (occ + t[:, None] * u + s[:, None] * np.column_stack((-u[:, 1], u[:, 0])))[group == 1]
    d, b = np.hypot(*balls.T), np.abs(np.arctan2(balls[:, 1], balls[:, 0]))
    keep = (d > 0.3) & (d < 5.5) & (b < HALF_FOV)                           # the ball always in view and range
    occ, balls = occ[keep], balls[keep]
    expected = rule(occ[:, 0], occ[:, 1], balls[:, 0], balls[:, 1])
    assert 0.08 < expected.mean() < 0.6, expected.mean()                     # both outcomes well represented
    visible = occlusion_case(preset, occ, balls)
    np.testing.assert_array_equal(visible, ~expected)
    if preset == "dynenv":                      # robots outside the view that would cover the ball do not hide it
        d_o = np.hypot(*occ.T)
        out_of_view = np.abs(np.arctan2(occ[:, 1], occ[:, 0])) > HALF_FOV + np.arcsin(np.minimum(1, 0.175 / d_o))
        across = np.abs(occ[:, 0] * balls[:, 1] - occ[:, 1] * balls[:, 0]) / d_o
        would_cover = out_of_view & (np.hypot(*balls.T) > d_o) & (across < BAND_RADIUS)
        assert would_cover.sum() > 50 and visible[would_cover].all(), would_cover.sum()


def test_the_band_ignores_robots_outside_the_view_and_the_cone_does_not():
    """The band (DynEnv): "Robots that fall inside the FOV occlude" — the same layout hides the ball when the robot
    is in view and not when it is just outside. The cone (realistic): any robot in front occludes."""
    def at(d, deg):
        return d * math.cos(math.radians(deg)), d * math.sin(math.radians(deg))
    # robot 1.0 m away, ball 1.6 m away 12° to its right: 1.6·sin 12° = 0.333 m < 0.35 m from the sight line
    inside = occlusion_case("dynenv", at(1.0, 12.0), [at(1.6, 0.0)])
    outside = occlusion_case("dynenv", at(1.0, 57.0), [at(1.6, 45.0)])    # robot beyond 45° + asin(0.175) = 55.1°
    assert not inside[0] and outside[0]
    # robot 0.8 m at 56.1°, beyond 45° + asin(0.15/0.8) = 55.8° (out of view); ball 1.5 m at 46° (in view up to
    # 45° + asin(0.05/1.5) = 46.9°), 10.1° from the robot's bearing, inside its half-width 10.8°
    assert not occlusion_case("realistic", at(0.8, 56.1), [at(1.5, 46.0)])[0]
    result = run(load_preset("realistic", mode="none"), [OBSERVER, Thing(ROBOT, *at(0.8, 56.1), 0.0, -1),
                                                         Thing(BALL, *at(1.5, 46.0))])
    assert len(result.detections) == 0                                      # neither the robot nor the ball


@pytest.mark.parametrize("preset", ["realistic", "dynenv"])
def test_nothing_is_hidden_by_a_robot_farther_away_than_the_object(preset):
    y = (np.arange(-40, 40) + 0.5) * 0.01                # the ball within 2.04 m: nearer than both robots
    for robot in ((4.0, 0.0), (2.05, 0.0)):
        assert occlusion_case(preset, robot, np.column_stack((np.full_like(y, 2.0), y))).all(), robot


@pytest.mark.parametrize("preset,mode", [("realistic", "realistic"), ("dynenv", "realistic"), ("dynenv", "random")])
def test_hidden_objects_are_never_reported_and_robots_hide_robots(preset, mode):
    """docs: "Hidden objects are never reported, in every mode"; docs/original.md §2.7: robots hide robots, balls."""
    params = load_preset(preset, noise_magnitude=3.0, mode=mode)
    things = [OBSERVER, Thing(ROBOT, 2.0, 0.0, 0.0, -1), Thing(BALL, 4.0, 0.05), Thing(ROBOT, 3.5, -0.1, 1.0, -1),
              Thing(ROBOT, 3.0, 1.4, 2.0, 1)]
    result = run(params, things, head_yaw=np.zeros(3000))
    assert not result.visible[:, 2:4].any() and result.visible[:, [1, 4]].all()
    true_ids = set(np.unique(result.detections["true_id"]))
    assert not true_ids & {2, 3} and {1, 4} <= true_ids


# ---- field of view, sighting bits and row order ---------------------------------------------------------------------
@pytest.mark.parametrize("preset", ["realistic", "dynenv"])
@pytest.mark.parametrize("cls", [BALL, ROBOT, POST])
def test_the_field_of_view_reaches_out_by_the_objects_radius(preset, cls):
    """docs "Geometry": an object of visibility radius r at distance d is in view if its bearing is within half the
    view + asin(r/d), PARTIAL if not at least asin(r/d) inside both edges (docs/original.md §2.7); bearings at 2 m."""
    d, r = 2.0, RADIUS[preset][cls]
    bearings = HALF_FOV + (np.arange(-40, 40) + 0.5) * 0.004                 # ±0.16 rad around the left edge
    xs = np.column_stack((np.zeros(len(bearings)), d * np.cos(bearings)))
    ys = np.column_stack((np.zeros(len(bearings)), d * np.sin(bearings)))
    result = run(load_preset(preset, mode="none"), [OBSERVER, Thing(cls, 0, 0, 0.0, -1)], xs=xs, ys=ys)
    reach = math.asin(r / d)
    np.testing.assert_array_equal(result.visible[:, 1], bearings <= HALF_FOV + reach)
    rows = result.detections
    assert len(rows) == (bearings <= HALF_FOV + reach).sum()
    np.testing.assert_array_equal((rows["sighting"] & Sighting.PARTIAL) > 0,
                                  bearings[result.visible[:, 1]] > HALF_FOV - reach)


# ---- sighting bits and row order come from the reports --------------------------------------------------------------
CLUSTER = [OBSERVER, Thing(BALL, 2.0, 0.3), Thing(ROBOT, 2.2, 0.5, 0.4, -1), Thing(ROBOT, 3.4, -1.1, 2.0, 1),
           Thing(BALL, 3.3, -1.3), Thing(POST, 4.4, 0.8), Thing(POST, 4.5, -0.75), Thing(CROSS, 3.2, 0.1),
           Thing(CROSSING, 2.9, 1.7, subtype=Subtype.CROSSING_T),
           Thing(CROSSING, 1.0, -0.9, subtype=Subtype.CROSSING_L),
           Thing(ROBOT, 5.0, 3.0, -1.0, -1, True), Thing(CIRCLE, 5.5, -1.0), Thing(BALL, 5.8, 0.9)]
LINES = [(2.5, -6.0, 2.9, 7.0), (0.5, 1.4, 6.0, 1.9), (1.5, -1.7, 4.0, -0.6), (3.5, -4.0, 3.7, -1.0),
         (-1.0, -1.0, -3.0, 2.0), (6.3, -2.0, 6.6, 3.0)]


@pytest.mark.parametrize("preset", ["realistic", "dynenv"])
def test_rows_come_nearest_first_with_sighting_bits_from_the_reported_position(preset):
    """docs "Nothing gives a false report away": every point report, real, confused or false alike, DISTANT iff
    d > near_range of the reported class; PARTIAL iff |bearing| > fov/2 − asin(min(1, r/d)), r the class's
    visibility radius; NEARBY iff another reported ball or robot of the same view is within 0.35 m. "Order: each
    frame's reports come nearest first"."""
    views = 3000
    head_yaw = np.random.default_rng(5).uniform(-1.5, 1.5, views)
    result = run(load_preset(preset, noise_magnitude=3.0), CLUSTER, LINES, head_yaw=head_yaw, seed=2)
    d = result.detections
    view = view_of_rows(result)
    x, y = d["x"].astype(float), d["y"].astype(float)
    dist = np.hypot(x, y)
    same_view = view[1:] == view[:-1]
    assert np.all(dist[1:][same_view] >= dist[:-1][same_view] - 1e-6), "rows of a view nearest first"
    point = np.isin(d["class_id"], (BALL, ROBOT, POST, CROSS, CROSSING))
    assert point.sum() + np.isin(d["class_id"], (LINE, CIRCLE)).sum() == len(d)
    near = np.array([CLASSES[preset][c][0] if c in CLASSES[preset] else np.inf for c in range(8)])
    radius = np.array([RADIUS[preset].get(c, 0.0) for c in range(8)])
    c = d["class_id"].astype(int)
    edge = HALF_FOV - np.arcsin(np.minimum(1.0, radius[c] / np.maximum(dist, 1e-9)))
    bearing = np.abs(np.arctan2(y, x))
    distant, partial = dist > near[c], bearing > edge
    dynamic = np.isin(c, (BALL, ROBOT))
    nearby, at_boundary = np.zeros(len(d), bool), np.zeros(len(d), bool)
    for k in range(1, int(np.diff(result.offsets).max())):        # every pair of rows of one view, k apart
        i = np.arange(len(d) - k)
        j = i + k
        gap = np.hypot(x[i] - x[j], y[i] - y[j])
        same = view[i] == view[j]
        for a, b in ((i, j), (j, i)):                              # b, a ball or robot, makes a NEARBY
            nearby[a[same & dynamic[b] & (gap < NEARBY_DISTANCE)]] = True
            at_boundary[a[same & dynamic[b] & (np.abs(gap - NEARBY_DISTANCE) < 1e-5)]] = True
    clear = point & (np.abs(dist - near[c]) > 1e-5) & (np.abs(bearing - edge) > 1e-5) & ~at_boundary
    assert clear.sum() > 0.999 * point.sum()
    expected = distant * int(Sighting.DISTANT) | partial * int(Sighting.PARTIAL) | nearby * int(Sighting.NEARBY)
    np.testing.assert_array_equal(d["sighting"][clear], expected[clear])
    false = d["true_id"] == -1
    for bit in (Sighting.DISTANT, Sighting.PARTIAL, Sighting.NEARBY):      # the rule meets real and false reports
        has = (d["sighting"] & bit) > 0
        assert (has & point & false).any() and (has & point & ~false).any(), bit


def test_the_centre_circle_is_partial_when_clipped_and_distant_beyond_its_near_range():
    """docs "Geometry": "Centre circle: seen when at least 3 of 36 rim samples are in view and range; PARTIAL unless
    all are"; DISTANT beyond its class's near_range (DynEnv 8.32 m)."""
    params = load_preset("dynenv", mode="none")
    clipped = run(params, [OBSERVER, Thing(CIRCLE, 3.0, 2.6)]).detections              # rim crosses the left edge
    far = run(params, [OBSERVER, Thing(CIRCLE, 10.0, 0.0)]).detections                  # whole rim in view, 10 m
    assert len(clipped) == 1 and clipped["sighting"][0] & Sighting.PARTIAL
    assert len(far) == 1 and far["sighting"][0] == Sighting.DISTANT


# ---- what made-up reports look like ---------------------------------------------------------------------------------
def test_false_and_confused_robots_look_like_another_robot_of_the_game():
    """docs "Made-up reports look like real ones of their class": a false or confused robot gets the heading
    (relative to the camera), team relation, fallen and penalized state of a random robot other than the observer;
    a crossing the shape of a random real crossing; every made-up report its class's size with the size error.
    Other made-up reports carry no robot attributes. DynEnv (yaw_std 0): the copied heading is exact."""
    observer = Thing(ROBOT, 0.0, 0.0, 0.0, 1, True, True)          # its own state must never be copied
    others = [Thing(ROBOT, -3.0, 1.0, 0.4, 1), Thing(ROBOT, -3.0, -1.0, -2.0, -1, True),
              Thing(ROBOT, -4.0, 0.0, 1.0, -1, False, True)]          # all behind the observer: never seen
    crossings = [Thing(CROSSING, -2.0, 2.0, subtype=Subtype.CROSSING_L),
                 Thing(CROSSING, -2.0, -2.0, subtype=Subtype.CROSSING_X)]
    marks = [Thing(BALL, -1.0, 0.0), Thing(POST, -4.5, 0.8), Thing(CROSS, -3.2, 0.0)]
    magnitude, views = 2.0, 20000
    params = load_preset("dynenv", noise_magnitude=magnitude)
    for observer_team in (-1, 1):            # the team relation: the copied robot's team seen by the observer's team
        result = run(params, [observer] + others + crossings + marks, head_yaw=np.zeros(views),
                     observer_team=observer_team)
        d = result.detections
        assert np.all(d["true_id"] == -1)
        robots = d[d["class_id"] == ROBOT]
        states = {(round(t.yaw, 5), t.team * observer_team, t.fallen, t.penalized) for t in others}
        got = [(round(float(r["yaw"]), 5), int(r["team"]), bool(r["fallen"]), bool(r["penalized"])) for r in robots]
        assert set(got) == states
        for state in states:
            assert_rate(got.count(state), len(got), 1 / 3, f"copied {state}")
    rest = d[d["class_id"] != ROBOT]
    assert np.isnan(rest["yaw"]).all() and not rest["team"].any() and not (rest["fallen"] | rest["penalized"]).any()
    shapes = d["subtype"][d["class_id"] == CROSSING]
    assert set(np.unique(shapes)) == {Subtype.CROSSING_L, Subtype.CROSSING_X}
    assert_rate(int((shapes == Subtype.CROSSING_L).sum()), len(shapes), 0.5, "crossing shape")
    assert not d["subtype"][~np.isin(d["class_id"], (CROSSING,))].any()
    # sizes: the size of the class's objects in the scene × (1 + N(0, m·0.058)) (docs table size_std 0.058)
    for cls in (BALL, ROBOT, POST, CROSS, CROSSING):
        mine = d[d["class_id"] == cls]
        assert_normal(mine["size_x"] / SIZE[cls], 1.0, magnitude * 0.058, f"{cls.name} size")
        np.testing.assert_array_equal(mine["size_x"], mine["size_y"])
    # confused: a far goalpost reported as a robot (realistic, rule goalpost → robot) copies another robot too
    params = load_preset("realistic", noise_magnitude=3.0)
    confused = run(params, [observer] + others + [Thing(POST, 6.0, 0.0)], head_yaw=np.zeros(views)).detections
    assert_normal(confused["size_x"][(confused["true_id"] == 4) & (confused["class_id"] == ROBOT)] / SIZE[ROBOT], 1.0,
                  3.0 * 0.05, "post reported as a robot: a robot's size")
    confused = confused[(confused["true_id"] == 4) & (confused["class_id"] == ROBOT)]
    assert len(confused) > 500
    assert {(int(r["team"]), bool(r["fallen"]), bool(r["penalized"])) for r in confused} == \
        {(t.team, t.fallen, t.penalized) for t in others}
    far_robot = run(params, [observer, Thing(ROBOT, 5.0, 0.0, 1.0, -1, True), Thing(POST, -4.5, 0.8)],
                    head_yaw=np.zeros(views)).detections
    as_post = far_robot[(far_robot["true_id"] == 1) & (far_robot["class_id"] == POST)]
    assert len(as_post) > 500 and np.isnan(as_post["yaw"]).all() and not as_post["team"].any()
    assert not as_post["fallen"].any()
    assert_normal(as_post["size_x"] / SIZE[POST], 1.0, 3.0 * 0.05, "robot reported as a post: a post's size")


def test_confidence_is_calibrated_in_realistic_and_one_in_dynenv():
    """docs "Confidence": evidence z ~ N(d', 1) for a correct report, N(0, 1) for a false or confused one; the score
    is sigmoid(logit(p_c) + d'·z − d'²/2) with d' = 1.5 and the ball's prior p_c = 0.81 (docs; realistic.yaml).
    So z recovered from a score is N(1.5, 1) for correct ball reports and N(0, 1) for the others.
    "confidence: none reports 1 (DynEnv has no confidence; the dynenv preset)"."""
    things = [OBSERVER, Thing(BALL, 2.0, 0.3), Thing(CROSS, 3.0, -0.5)]
    dynenv = run(load_preset("dynenv", noise_magnitude=5.0), things, LINES, head_yaw=np.zeros(2000)).detections
    assert (dynenv["true_id"] == -1).any() and np.all(dynenv["confidence"] == 1.0)
    d = run(load_preset("realistic", noise_magnitude=5.0), things, head_yaw=np.zeros(20000)).detections
    balls = d[d["class_id"] == BALL]
    score = balls["confidence"].astype(float)
    assert np.all((score > 0) & (score < 1))
    z = (np.log(score / (1 - score)) - math.log(0.81 / 0.19) + 1.5 ** 2 / 2) / 1.5
    correct = (balls["true_id"] >= 0) & (balls["true_class"] == BALL)
    assert (~correct).sum() > 1000
    assert_normal(z[correct], 1.5, 1.0, "evidence of correct ball reports")
    assert_normal(z[~correct], 0.0, 1.0, "evidence of false and confused ball reports")


# ---- no absolute pose leaks: rigid motions and mirror images, field lines included ----------------------------------
def rigid(things, lines, angle, shift):
    """The whole scene (observer, objects, lines in their stored order) rotated by ``angle`` and shifted."""
    c, s = math.cos(angle), math.sin(angle)
    move = lambda x, y: (c * x - s * y + shift[0], s * x + c * y + shift[1])    # noqa: E731
    things = [t._replace(x=move(t.x, t.y)[0], y=move(t.x, t.y)[1], yaw=t.yaw + angle) for t in things]
    lines = [(*move(x1, y1), *move(x2, y2)) for x1, y1, x2, y2 in lines]
    return things, lines


def mirror(things, lines, heading):
    """The whole scene mirrored across the observer's line of gaze (through things[0] at ``heading``)."""
    ox, oy = things[0].x, things[0].y
    c, s = math.cos(2 * heading), math.sin(2 * heading)
    flip = lambda x, y: (ox + c * (x - ox) + s * (y - oy), oy + s * (x - ox) - c * (y - oy))   # noqa: E731
    things = [t._replace(x=flip(t.x, t.y)[0], y=flip(t.x, t.y)[1], yaw=2 * heading - t.yaw) for t in things]
    lines = [(*flip(x1, y1), *flip(x2, y2)) for x1, y1, x2, y2 in lines]
    return things, lines


def assert_same_reports(a, b, mirrored=False):
    """Report for report equal (``mirrored``: y, yaw and the endpoints' y negated, endpoint order kept)."""
    np.testing.assert_array_equal(a.offsets, b.offsets)
    a, b = a.detections, b.detections
    for name in ("class_id", "team", "fallen", "penalized", "subtype", "sighting", "true_id", "true_class"):
        np.testing.assert_array_equal(a[name], b[name], err_msg=name)
    sign = -1.0 if mirrored else 1.0
    for name, k in (("x", 1), ("y", sign), ("size_x", 1), ("size_y", 1), ("confidence", 1), ("line_start_x", 1),
                    ("line_start_y", sign), ("line_end_x", 1), ("line_end_y", sign)):
        np.testing.assert_allclose(a[name], k * b[name], atol=2e-4, err_msg=name)
    yaw_a, yaw_b = a["yaw"].astype(float), sign * b["yaw"].astype(float)
    np.testing.assert_array_equal(np.isnan(yaw_a), np.isnan(yaw_b))
    period = np.where(a["class_id"] == LINE, math.pi, 2 * math.pi)           # a line's direction is mod π
    defined = ~np.isnan(yaw_a)
    gap = np.mod(yaw_a - yaw_b + period / 2, period) - period / 2
    np.testing.assert_allclose(gap[defined], 0.0, atol=2e-4, err_msg="yaw")


HEAD_YAWS = np.tile([-0.5, 0.0, 0.3, 0.8, -1.2], 40)
PRESETS = [("none", {}), ("realistic", {"noise_magnitude": 2.0}), ("dynenv", {"noise_magnitude": 2.0}),
           ("realistic", {"noise_magnitude": 2.0, "mode": "random"}), ("realistic", {"mode": "none"}),
           ("dynenv", {"mode": "none"})]


@pytest.mark.parametrize("preset,overrides", PRESETS)
def test_detections_do_not_depend_on_where_the_observer_stands_or_faces(preset, overrides):
    """docs: "no absolute heading or position (a test rotates, shifts and mirrors the whole scene, lines included,
    and gets the same or the mirrored detections)". The whole scene — observer, ball, robots, posts, marks,
    crossings, circle and field lines — moved rigidly gives the same reports (with noise: for the same seed);
    docs/original.md §12.3: DynEnv leaked a compass."""
    params = load_preset(preset, **overrides)
    a = run(params, *rigid(CLUSTER, LINES, 0.7, (-1.0, 0.5)), head_yaw=HEAD_YAWS, seed=3)
    b = run(params, *rigid(CLUSTER, LINES, -2.4, (3.5, -2.0)), head_yaw=HEAD_YAWS, seed=3)
    assert len(a.detections) > 5 * len(HEAD_YAWS)
    assert set(np.unique(a.detections["class_id"])) >= {BALL, ROBOT, POST, CROSS, CROSSING, LINE, CIRCLE}
    assert_same_reports(a, b)


@pytest.mark.parametrize("preset", ["realistic", "dynenv"])
@pytest.mark.parametrize("head_yaw", [-0.5, 0.0, 0.3, 0.8, -1.2])
def test_a_mirrored_situation_gives_mirrored_detections(preset, head_yaw):
    """The scene mirrored across the camera's line of gaze gives the mirror image of every report: y → −y,
    yaw → −yaw, line endpoints mirrored and in the same order (no noise: mode none with the preset's geometry).
    docs "Lines": "line_start the nearer end ... so a mirrored situation gives the mirrored report"."""
    params = load_preset(preset, mode="none")
    things, lines = rigid(CLUSTER, LINES, 0.9, (1.0, -2.0))
    heading = things[0].yaw + head_yaw
    a = run(params, things, lines, head_yaw=[head_yaw])
    b = run(params, *mirror(things, lines, heading), head_yaw=[-head_yaw])
    assert (a.detections["class_id"] == LINE).any()
    assert_same_reports(a, b, mirrored=True)


def test_a_mirrored_situation_gives_mirrored_detections_in_distribution():
    """With noise the mirror image holds in distribution: per view, as many reports of each class and sighting;
    reported y of each object and of line endpoints mirrored on average (two-sample, SIGMAS standard errors)."""
    params = load_preset("realistic", noise_magnitude=3.0)
    views = 10000
    things, lines = rigid(CLUSTER, LINES, 0.9, (1.0, -2.0))
    a = run(params, things, lines, head_yaw=np.full(views, 0.3), seed=1)
    b = run(params, *mirror(things, lines, things[0].yaw + 0.3), head_yaw=np.full(views, -0.3), seed=2)

    def same_mean(u, v, what):
        se = math.sqrt(u.var(ddof=1) / len(u) + v.var(ddof=1) / len(v))
        assert abs(u.mean() - v.mean()) <= SIGMAS * se + 1e-12, f"{what}: {u.mean()} vs {v.mean()}"

    for cls in (BALL, ROBOT, POST, CROSS, CROSSING, LINE, CIRCLE):
        for bit in (Sighting.NORMAL, Sighting.DISTANT, Sighting.PARTIAL, Sighting.NEARBY):
            counts = [np.bincount(view_of_rows(r)[(r.detections["class_id"] == cls) & (
                (r.detections["sighting"] & bit) > 0 if bit else r.detections["sighting"] == 0)], minlength=views)
                for r in (a, b)]
            same_mean(*counts, f"{cls.name} {bit!r} per view")
    for i in range(1, len(things)):
        ya = a.detections["y"][a.detections["true_id"] == i].astype(float)
        yb = b.detections["y"][b.detections["true_id"] == i].astype(float)
        if len(ya) > 100:
            same_mean(ya, -yb, f"object {i} y")
    for k in range(len(lines)):
        for end in ("line_start_y", "line_end_y"):
            ya = a.detections[end][a.detections["true_id"] == -2 - k].astype(float)
            yb = b.detections[end][b.detections["true_id"] == -2 - k].astype(float)
            if len(ya) > 100:
                same_mean(ya, -yb, f"line {k} {end}")


def field_lines(turn):
    """A vertical and a horizontal field line as a field stores them (lower coordinate first), seen by an observer
    at the origin facing ``turn``: the field is turned with it, so the view is the same for every ``turn``."""
    c, s = round(math.cos(turn)), round(math.sin(turn))
    def at(x, y):
        return c * x - s * y, s * x + c * y
    lines = []
    for a, b in (((3.0, -1.0), (3.0, 5.0)), ((0.5, 1.0), (5.0, 1.0))):    # in the observer's frame
        (x1, y1), (x2, y2) = at(*a), at(*b)
        lines.append((x1, y1, x2, y2) if (x1, y1) < (x2, y2) else (x2, y2, x1, y1))   # field order
    return lines


@pytest.mark.parametrize("preset,overrides", [("none", {}), ("realistic", {"noise_magnitude": 1.0}),
                                              ("dynenv", {"noise_magnitude": 1.0})])
def test_line_endpoint_order_does_not_follow_the_field(preset, overrides):
    """Regression (docs/original.md §12.3, a line's stored direction is a compass): from headings 0, 90°, 180° and 270°
    with the field turned along, the reports are the same and each line's nearer endpoint comes first — the vertical
    line from (3, −1) to (3, 3) (clipped by the view's left edge), the horizontal from (1, 1) (clipped) to (5, 1)."""
    params = load_preset(preset, **overrides)
    reports = []
    for turn in (0.0, math.pi / 2, math.pi, -math.pi / 2):
        observer = OBSERVER._replace(yaw=turn)
        result = run(params, [observer], field_lines(turn), head_yaw=np.zeros(500), seed=4)
        d = result.detections[result.detections["class_id"] == LINE]
        near = np.hypot(d["line_start_x"], d["line_start_y"])
        assert np.all(near <= np.hypot(d["line_end_x"], d["line_end_y"])), "nearer endpoint first"
        reports.append(d)
    vertical, horizontal = (reports[0][reports[0]["true_id"] == i] for i in (-2, -3))
    expected = {-2: (3.0, -1.0, 3.0, 3.0), -3: (1.0, 1.0, 5.0, 1.0)}
    tolerance = 1e-5 if preset == "none" else 0.2
    for rows, k in ((vertical, -2), (horizontal, -3)):
        ends = np.column_stack([rows[f] for f in ("line_start_x", "line_start_y", "line_end_x", "line_end_y")])
        np.testing.assert_allclose(ends.mean(axis=0), expected[k], atol=tolerance)
    if preset == "none":
        for other in reports[1:]:
            np.testing.assert_allclose(
                np.column_stack([other[f] for f in ("line_start_x", "line_start_y", "line_end_x", "line_end_y")]),
                np.column_stack([reports[0][f] for f in ("line_start_x", "line_start_y", "line_end_x",
                                                         "line_end_y")]), atol=1e-5)


def test_equidistant_line_endpoints_are_not_ordered_by_the_field():
    """A line square to the gaze, clipped symmetrically by both edges: its endpoints are equally far, and the order
    must still not depend on how the field stores the line nor on the heading (0 vs 180° with the field turned)."""
    params = load_preset("none")
    forward = run(params, [OBSERVER], [(2.0, -10.0, 2.0, 10.0)]).detections
    backward = run(params, [OBSERVER], [(2.0, 10.0, 2.0, -10.0)]).detections
    turned = run(params, [OBSERVER._replace(yaw=math.pi)], [(-2.0, -10.0, -2.0, 10.0)]).detections
    for other in (backward, turned):
        assert (forward["line_start_y"][0], forward["line_end_y"][0]) == pytest.approx(
            (other["line_start_y"][0], other["line_end_y"][0]), abs=1e-5)
