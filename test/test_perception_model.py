"""The perception error model, checked statistically: each rule of each preset shows up at its documented rate.

The expected values are the documented formulas written out here with the presets' documented numbers as literals
(docs/perception.md, "Error model" and "Parameters and presets"; the original's numbers in
docs/original.md §2.7 and §5.1; a number only the YAML states cites config/perception/<preset>.yaml).
Nothing expected is read from the parameters or computed by the model's own code, so a preset that drifts from its
documented numbers fails. Tolerances are ``SIGMAS`` standard errors of the sample at hand (binomial for rates,
normal or chi-square for means and spreads, Kolmogorov for shapes): a correct model fails about once in a million
runs (the seeds are fixed, so in practice never), while a factor of 1.5 in any tested number fails.
Geometry (occlusion, sighting bits, invariance, mirroring) is in test_perception_geometry.py.
"""
import math
from dataclasses import replace

import numpy as np
import pytest

from dynenv_ros.core.object_classes import ObjectClass, Sighting
from dynenv_ros.perception.model import Perception, Perceiver
from dynenv_ros.perception.params import from_mapping, load_preset, load_yaml
from dynenv_ros.perception.scene import SceneFrames, SceneObjects, Views

ROBOT, BALL, POST, CROSS = ObjectClass.ROBOT, ObjectClass.BALL, ObjectClass.GOALPOST, ObjectClass.PENALTY_CROSS
CROSSING, LINE, CIRCLE = ObjectClass.LINE_CROSSING, ObjectClass.FIELD_LINE, ObjectClass.CENTER_CIRCLE
SIZE = {ROBOT: 0.2, BALL: 0.1, POST: 0.1, CROSS: 0.1, CROSSING: 0.1}
SIGMAS = 5.0
HALF_FOV = math.pi / 4          # docs "Parameters and presets": field_of_view 90°, both presets; docs/original.md §2.7

# ---- the documented numbers, written out (each cross-checked against the preset YAML and docs/perception.md) ----
# Per class: (near_range, max_range, miss_scale). Realistic: docs/perception.md "Parameters and presets" rows
# "ball ... 3.0 m / 6.0 m", "robot 4.0 / 7.0", "goalpost 5.0 / 9.0", "penalty cross, line crossing 3.0 / 4.5–5.0",
# "field line, circle 4.0 / 6.0" and "miss_scale ball / cross / crossing / circle 1.5 / 1.5 / 2 / 1.5"
# (= config/perception/realistic.yaml classes). DynEnv: 4.16 m / 8.32 m, no cut-off, miss_scale 1 (docs table;
# docs/original.md §2.7: 416 px for ball, penalty crosses and field crosses, 832 px for robots, goalposts, lines and
# the centre circle, "There is no hard range limit"; 1 px = 1 cm).
CLASSES = {
    "realistic": {BALL: (3.0, 6.0, 1.5), ROBOT: (4.0, 7.0, 1.0), POST: (5.0, 9.0, 1.0), CROSS: (3.0, 4.5, 1.5),
                  CROSSING: (3.0, 5.0, 2.0), LINE: (4.0, 6.0, 1.0), CIRCLE: (4.0, 6.0, 1.5)},
    "dynenv": {BALL: (4.16, math.inf, 1.0), ROBOT: (8.32, math.inf, 1.0), POST: (8.32, math.inf, 1.0),
               CROSS: (4.16, math.inf, 1.0), CROSSING: (4.16, math.inf, 1.0), LINE: (8.32, math.inf, 1.0),
               CIRCLE: (8.32, math.inf, 1.0)},
}
# Visibility radii: realistic from config/perception/realistic.yaml (docs do not list them); DynEnv from
# docs/original.md §2.7 "radii used for visibility: ball 10, robot 17.5, goalpost 5, crosses 5" px
# (= config/perception/dynenv.yaml).
RADIUS = {"realistic": {BALL: 0.05, ROBOT: 0.15, POST: 0.05, CROSS: 0.05, CROSSING: 0.05},
          "dynenv": {BALL: 0.10, ROBOT: 0.175, POST: 0.05, CROSS: 0.05, CROSSING: 0.05}}
# Uniform false positives: docs "false positives | 10 trials × 0.01, 8.32 m | 10 × 0.01, 6 m"; docs/original.md §5.1
# "10 trials per observation, each firing with probability ρ", "6 options uniformly: ball, robot, post, penalty
# cross, field cross, or none", "distance U·832 px".
FP_TRIALS, FP_PROBABILITY, FP_REAL_SHARE = 10, 0.01, 5 / 6
FP_MAX_DISTANCE = {"realistic": 6.0, "dynenv": 8.32}
# Confusions, P = probability·ρ·m(d): docs "each confusions rule: P = probability·ρ·m(d) (optionally only DISTANT)";
# ball ↔ penalty cross 0.5 in both presets (docs table; docs/original.md §5.1 "ρ·multiplier/2"); robot → goalpost 1.0
# and goalpost → robot 0.5, DISTANT only, realistic only (the docs name the rules, config/perception/realistic.yaml
# their probabilities).
CONFUSION = {"realistic": {BALL: (CROSS, 0.5, False), CROSS: (BALL, 0.5, False), ROBOT: (POST, 1.0, True),
                           POST: (ROBOT, 0.5, True)},
             "dynenv": {BALL: (CROSS, 0.5, False), CROSS: (BALL, 0.5, False)}}


def multiplier(distance, near, sighting=None):
    """docs "Error model": m(d) = (0.25 + 3.75·(d/near_range)²) × 4 if PARTIAL, else 3 if DISTANT, else 2 if NEARBY
    (docs/original.md §5.1: "range = 0.25 + 3.75·|p|²/maxVisDist", "Distant/Partial override Nearby")."""
    return (0.25 + 3.75 * (distance / near) ** 2) * {None: 1, "nearby": 2, "distant": 3, "partial": 4}[sighting]


def p_miss(magnitude, miss_scale, mult):
    """docs "Error model": P(miss) = ρ·miss_scale·m(d), ρ = 0.01·magnitude (docs/original.md §5.1 "FN with
    probability ρ·multiplier")."""
    return min(1.0, 0.01 * magnitude * miss_scale * mult)


def p_confuse(magnitude, probability, mult):
    return min(1.0, probability * 0.01 * magnitude * mult)


# ---- scenes and checks ----------------------------------------------------------------------------------------------
def scene(objects, views=1, lines=()):
    """Observer = object 0, a team-A robot at the origin looking along +x; ``objects`` = (class, x, y, yaw, team,
    fallen)."""
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


CHUNK = 500     # views per perceive call: bounds a test's memory on a shared machine whatever the model does


def perceive_in_chunks(perceiver, frames, views, rng, observer_team):
    """``perceiver.perceive`` of all views, CHUNK views at a time with one generator, as one Perception."""
    parts = []
    for start in range(0, len(views), CHUNK):
        part = slice(start, start + CHUNK)
        parts.append(perceiver.perceive(frames, Views(frame=views.frame[part], observer=views.observer[part],
                                                      head_yaw=views.head_yaw[part]), rng, observer_team[part]))
    if len(parts) == 1:
        return parts[0]
    starts = np.cumsum([0] + [len(p.detections) for p in parts[:-1]])
    offsets = np.concatenate([[0]] + [p.offsets[1:] + s for p, s in zip(parts, starts)])
    return Perception(np.concatenate([p.detections for p in parts]), offsets, np.vstack([p.seen for p in parts]),
                      np.concatenate([p.lines_seen for p in parts]), np.vstack([p.visible for p in parts]))


def perceive(params, objects, views=1, seed=0, lines=()):
    obj, frames, v = scene(objects, views, lines)
    return perceive_in_chunks(Perceiver(obj, params), frames, v, np.random.default_rng(seed), np.ones(views, np.int8))


def reported_as(perception, object_id=1):
    """(V,) per view: the class object ``object_id`` was reported as, 0 where it has no row."""
    d = perception.detections
    view = np.repeat(np.arange(len(perception)), np.diff(perception.offsets))
    out = np.zeros(len(perception), int)
    mine = d["true_id"] == object_id
    assert len(np.unique(view[mine])) == mine.sum(), "an object has at most one row per view"
    out[view[mine]] = d["class_id"][mine]
    return out


def assert_rate(successes, trials, p, what=""):
    """successes/trials within SIGMAS binomial standard errors of p; exact where p is 0 or 1."""
    if p <= 0.0 or p >= 1.0:
        assert successes == round(p * trials), f"{what}: {successes}/{trials}, expected rate {p}"
        return
    se = math.sqrt(p * (1 - p) / trials)
    assert abs(successes / trials - p) <= SIGMAS * se, \
        f"{what}: {successes / trials:.5f}, expected {p:.5f} ± {SIGMAS * se:.5f} ({SIGMAS:g} SE, n={trials})"


def assert_normal(sample, mean, sigma, what=""):
    """Sample mean within SIGMAS standard errors of ``mean``, variance within SIGMAS chi-square standard errors of
    sigma² (the normal approximation of χ²(n−1)/(n−1): SE √(2/(n−1)))."""
    sample = np.asarray(sample, float)
    n = len(sample)
    assert n > 100, f"{what}: too few samples ({n})"
    assert abs(sample.mean() - mean) <= SIGMAS * sigma / math.sqrt(n), f"{what}: mean {sample.mean()} vs {mean}"
    ratio = sample.var(ddof=1) / sigma ** 2
    assert abs(ratio - 1) <= SIGMAS * math.sqrt(2 / (n - 1)), \
        f"{what}: σ {sample.std(ddof=1):.5f} vs documented {sigma:.5f} (n={n})"


def assert_uniform(sample, low, high, what="", atol=1e-6):
    """Uniform on [low, high]: inside it (± atol, the float32 rounding of a report), mean within SIGMAS SE, and the
    Kolmogorov–Smirnov distance below 2.8/√n (P(K > 2.8) ≈ 2·exp(−2·2.8²) ≈ 3e-7, the tail of 5 normal SE)."""
    sample = np.sort(np.asarray(sample, float))
    assert sample[0] >= low - atol and sample[-1] <= high + atol, f"{what}: outside [{low}, {high}]: " \
        f"{sample[0]}, {sample[-1]}"
    u = (sample - low) / (high - low)
    n = len(u)
    assert n > 100, f"{what}: too few samples ({n})"
    assert abs(u.mean() - 0.5) <= SIGMAS / math.sqrt(12 * n), f"{what}: mean {u.mean()} of U(0, 1)"
    i = np.arange(1, n + 1)
    ks = max((i / n - u).max(), (u - (i - 1) / n).max())
    assert ks < 2.8 / math.sqrt(n), f"{what}: KS distance {ks:.4f} from uniform (n={n})"


# ---- the presets hold the documented numbers ------------------------------------------------------------------------
@pytest.mark.parametrize("preset", ["realistic", "dynenv"])
def test_presets_hold_the_documented_numbers(preset):
    """The literal tables above against the preset files (a clear message before any statistics run)."""
    params = load_preset(preset)
    for cls, (near, far, scale) in CLASSES[preset].items():
        c = params.classes[cls]
        assert (c.near_range, c.max_range, c.miss_scale) == (near, far, scale), cls.name
    for cls, radius in RADIUS[preset].items():
        assert params.classes[cls].visibility_radius == radius, cls.name
    miss = params.miss     # docs table: "miss.base, range_offset, range_slope, factors 2/3/4 | 0.01, 0.25, 3.75 | same"
    assert (miss.base, miss.range_offset, miss.range_slope) == (0.01, 0.25, 3.75)
    assert (miss.nearby_factor, miss.distant_factor, miss.partial_factor, miss.nearby_distance) == (2, 3, 4, 0.35)
    fp = params.false_positives
    assert (fp.trials, fp.probability, fp.max_distance) == (FP_TRIALS, FP_PROBABILITY, FP_MAX_DISTANCE[preset])
    assert (fp.at_feet_probability, fp.at_feet_range, fp.at_feet_robot_dropped) == (0.1, 2.5, 0.08)
    assert len(fp.classes) == 6 and fp.classes.count(ObjectClass.UNKNOWN) == 1
    rules = {c.source: (c.target, c.probability, c.distant_only) for c in params.confusions}
    assert rules == CONFUSION[preset]
    assert params.field_of_view == pytest.approx(2 * HALF_FOV, abs=1e-6)
    assert params.confidence == {"realistic": "calibrated", "dynenv": "none"}[preset]
    assert (params.occlusion.model, params.occlusion.occluder_radius) == {"realistic": ("cone", 0.15),
                                                                          "dynenv": ("band", 0.35)}[preset]


# ---- rule 1: misses grow with distance ------------------------------------------------------------------------------
@pytest.mark.parametrize("preset,magnitude", [("realistic", 1.0), ("realistic", 3.0), ("dynenv", 2.0)])
@pytest.mark.parametrize("distance", [1.0, 2.5, 3.5, 5.5, 6.5])
def test_miss_and_confusion_rates_follow_the_documented_formula(preset, magnitude, distance):
    """A ball straight ahead: P(miss) = 0.01·m·miss_scale·(0.25 + 3.75·(d/near)²)·(3 if DISTANT); a ball that is
    not missed becomes a penalty cross with P = 0.5·0.01·m·mult; beyond max_range it is never seen."""
    views = 40000
    near, max_range, scale = CLASSES[preset][BALL]
    result = perceive(load_preset(preset, noise_magnitude=magnitude), [(BALL, distance, 0.0, np.nan, 0, False)], views)
    outcome = reported_as(result)
    if distance > max_range:
        assert not result.visible[:, 1].any() and not outcome.any()
        return
    assert result.visible[:, 1].all()
    mult = multiplier(distance, near, "distant" if distance > near else None)
    missed = p_miss(magnitude, scale, mult)
    confused = (1 - missed) * p_confuse(magnitude, 0.5, mult)
    assert_rate(int((outcome == 0).sum()), views, missed, "missed")
    assert_rate(int((outcome == CROSS).sum()), views, confused, "reported as a penalty cross")
    assert int(result.seen[:, 1].sum()) == int((outcome == BALL).sum())   # confused sightings are not "truly seen"


@pytest.mark.parametrize("preset,magnitude", [("realistic", 4.0), ("dynenv", 2.0)])
def test_random_mode_misses_at_a_fixed_rate_whatever_the_distance(preset, magnitude):
    """docs "Error model", random: multiplier 1, P(miss) = ρ·miss_scale, no confusions (docs/original.md §5.1)."""
    params = load_preset(preset, mode="random", noise_magnitude=magnitude)
    scale = CLASSES[preset][BALL][2]
    for distance in (1.0, 5.0):
        outcome = reported_as(perceive(params, [(BALL, distance, 0.0, np.nan, 0, False)], 20000))
        assert_rate(int((outcome == 0).sum()), 20000, 0.01 * magnitude * scale, f"missed at {distance} m")
        assert not (outcome == CROSS).any()


@pytest.mark.parametrize("situation", ["nearby", "distant and nearby", "partial", "partial and distant"])
def test_nearby_partial_and_distant_multiply_the_miss_rate(situation):
    """docs "Error model": ×4 if PARTIAL, else ×3 if DISTANT, else ×2 if NEARBY (another ball or robot within
    0.35 m); docs/original.md §5.1 "Distant/Partial override Nearby". Realistic ball: near 3.0 m, miss_scale 1.5."""
    magnitude, views = 3.0, 20000
    d, bearing, neighbour, factor = {"nearby": (1.5, 0.0, True, "nearby"),
                                     "distant and nearby": (3.5, 0.0, True, "distant"),
                                     "partial": (2.0, HALF_FOV, False, "partial"),
                                     "partial and distant": (3.2, HALF_FOV, False, "partial")}[situation]
    x, y = d * math.cos(bearing), d * math.sin(bearing)
    objects = [(BALL, x, y, np.nan, 0, False)]
    if neighbour:                                   # 0.3 m to the side, a little farther: it hides nothing
        objects.append((ROBOT, x, y + 0.3, 0.0, -1, False))
    outcome = reported_as(perceive(load_preset("realistic", noise_magnitude=magnitude), objects, views))
    mult = multiplier(d, 3.0, factor)
    missed = p_miss(magnitude, 1.5, mult)
    assert_rate(int((outcome == 0).sum()), views, missed, f"missed, {situation}")
    assert_rate(int((outcome == CROSS).sum()), views, (1 - missed) * p_confuse(magnitude, 0.5, mult), "confused")


@pytest.mark.parametrize("preset,magnitude", [("realistic", 3.0), ("dynenv", 3.0)])
def test_field_lines_are_missed_by_the_mean_multiplier_of_their_ends(preset, magnitude):
    """docs/original.md §5.1 (addNoiseLine): per endpoint mult_i = 0.25 + 3.75·(d_i/near)², P(miss) = ρ·mean(mult_i),
    the sighting type ignored (no ×4 for a clipped line). Field line near: realistic 4.0 m, DynEnv 8.32 m."""
    near = CLASSES[preset][LINE][0]
    params = load_preset(preset, noise_magnitude=magnitude)
    views = 20000
    for line, ends in (((2.0, -0.5, 3.5, 0.5), ((2.0, -0.5), (3.5, 0.5))),        # wholly in view
                       ((2.0, -10.0, 2.0, 10.0), ((2.0, -2.0), (2.0, 2.0)))):    # clipped by both edges: PARTIAL
        result = perceive(params, [], views, lines=[line])
        mean_mult = np.mean([multiplier(math.hypot(*end), near) for end in ends])
        assert_rate(views - int(result.lines_seen.sum()), views, p_miss(magnitude, 1.0, mean_mult), f"line {line}")


# ---- rule 3: similar classes are confused ---------------------------------------------------------------------------
@pytest.mark.parametrize("preset,magnitude", [("realistic", 3.0), ("dynenv", 3.0)])
@pytest.mark.parametrize("source", [BALL, CROSS])
def test_balls_and_penalty_crosses_are_confused_at_the_documented_rate(preset, magnitude, source):
    views, distance = 40000, 2.0
    near, _, scale = CLASSES[preset][source]
    target = CROSS if source == BALL else BALL
    result = perceive(load_preset(preset, noise_magnitude=magnitude), [(source, distance, 0.0, np.nan, 0, False)],
                      views)
    outcome = reported_as(result)
    mult = multiplier(distance, near)
    missed = p_miss(magnitude, scale, mult)
    assert_rate(int((outcome == target).sum()), views, (1 - missed) * p_confuse(magnitude, 0.5, mult), "confused")
    rows = result.detections[result.detections["true_id"] == 1]
    assert np.all(rows["true_class"] == source)
    assert int(result.seen[:, 1].sum()) == int((outcome == source).sum())


def test_robots_and_goalposts_are_confused_only_at_a_distance():
    """realistic: robot → goalpost (1.0) and goalpost → robot (0.5), DISTANT only (beyond 4.0 m / 5.0 m)."""
    params = load_preset("realistic", noise_magnitude=3.0)
    views = 20000
    for source, target, near, d_near, d_far, probability in ((ROBOT, POST, 4.0, 2.0, 5.0, 1.0),
                                                             (POST, ROBOT, 5.0, 4.0, 6.0, 0.5)):
        yaw = 0.0 if source == ROBOT else np.nan
        assert not (reported_as(perceive(params, [(source, d_near, 0.0, yaw, -1, False)], views)) == target).any()
        outcome = reported_as(perceive(params, [(source, d_far, 0.0, yaw, -1, False)], views))
        mult = multiplier(d_far, near, "distant")
        missed = p_miss(3.0, 1.0, mult)
        assert_rate(int((outcome == target).sum()), views, (1 - missed) * p_confuse(3.0, probability, mult),
                    f"{source.name} as {target.name}")
    # DynEnv confuses only balls and penalty crosses (docs/original.md §5.1 "Robots, posts and field crosses are never
    # misclassified")
    dynenv = load_preset("dynenv", noise_magnitude=3.0)
    for source, target in ((ROBOT, POST), (POST, ROBOT)):
        yaw = 0.0 if source == ROBOT else np.nan
        assert not (reported_as(perceive(dynenv, [(source, 9.0, 0.0, yaw, -1, False)], views)) == target).any()


# ---- rule 4: false positives ----------------------------------------------------------------------------------------
@pytest.mark.parametrize("preset,magnitude,views", [("realistic", 1.0, 40000), ("realistic", 3.0, 20000),
                                                    ("dynenv", 2.0, 20000)])
def test_false_positives_per_frame_and_where_they_appear(preset, magnitude, views):
    """Per frame Binomial(10, 0.01·m) trials, a class drawn from 6 (none = nothing): 5/6 of them real, one fifth
    each; distance uniform up to min(max_distance, the class's max_range); bearing uniform within
    ±(fov/2 + asin(min(1, r/max(d, 2r)))), r the class's visibility radius (docs "Made-up reports look like real
    ones of their class": "uniformly in distance up to max_distance and the class's max_range, and in bearing
    across the view widened by the class's reach asin(r / max(d, 2r))")."""
    result = perceive(load_preset(preset, noise_magnitude=magnitude), [], views)
    fps = result.detections[result.detections["true_id"] == -1]
    q = FP_PROBABILITY * magnitude * FP_REAL_SHARE          # per trial: fires and draws a real class
    expected = FP_TRIALS * q
    se = math.sqrt(FP_TRIALS * q * (1 - q) / views)
    assert abs(len(fps) / views - expected) <= SIGMAS * se, (len(fps) / views, expected)
    classes = (BALL, ROBOT, POST, CROSS, CROSSING)
    assert set(np.unique(fps["class_id"])) == set(classes)
    for cls in classes:
        mine = fps[fps["class_id"] == cls]
        assert_rate(len(mine), len(fps), 1 / 5, f"share of {cls.name}")
        limit = min(FP_MAX_DISTANCE[preset], CLASSES[preset][cls][1])
        distance = np.hypot(mine["x"].astype(float), mine["y"].astype(float))
        assert_uniform(distance, 0.0, limit, f"{cls.name} distance")
        r = RADIUS[preset][cls]
        reach = np.arcsin(np.minimum(1.0, r / np.maximum(distance, 2 * r)))
        bearing = np.arctan2(mine["y"], mine["x"]).astype(float)
        assert_uniform(bearing / (HALF_FOV + reach), -1.0, 1.0, f"{cls.name} bearing / its edge")
        # beyond the view's edge (where partially seen real objects are) with P = reach / (fov/2 + reach) each
        p_out = reach / (HALF_FOV + reach)
        outside = int((np.abs(bearing) > HALF_FOV).sum())
        assert abs(outside - p_out.sum()) <= SIGMAS * math.sqrt((p_out * (1 - p_out)).sum()), \
            (cls.name, outside, p_out.sum())


@pytest.mark.parametrize("preset", ["realistic", "dynenv"])
def test_balls_appear_at_the_feet_of_nearby_robots_and_sometimes_replace_them(preset):
    """docs rule (4): per robot seen (not DISTANT/PARTIAL) closer than 2.5 m, a ball at its feet with P = 0.1·m,
    and then the robot itself unreported with P = 0.08·m (both presets; docs/original.md §5.1 "10ρ", "8ρ", "250 px").
    Uniform false positives are switched off so that every false ball is one at the feet."""
    magnitude, views = 2.0, 40000
    params = load_preset(preset, noise_magnitude=magnitude)
    params = replace(params, false_positives=replace(params.false_positives, probability=0.0))
    near, _, scale = CLASSES[preset][ROBOT]
    result = perceive(params, [(ROBOT, 1.5, 0.0, math.pi, -1, False)], views)
    d = result.detections
    feet = d[(d["true_id"] == -1) & (d["class_id"] == BALL)]
    assert len(d[d["true_id"] == -1]) == len(feet)
    robot_kept = 1 - p_miss(magnitude, scale, multiplier(1.5, near))
    assert_rate(len(feet), views, robot_kept * 0.1 * magnitude, "balls at the feet")
    unreported = views - int((reported_as(result) == ROBOT).sum())
    assert_rate(unreported, views, 1 - robot_kept * (1 - 0.1 * magnitude * 0.08 * magnitude), "robot unreported")
    assert np.all(np.hypot(feet["x"] - 1.5, feet["y"]) < 1.0)        # at its feet, not anywhere
    for x, y in ((3.0, 0.0), (1.5 * math.cos(HALF_FOV), 1.5 * math.sin(HALF_FOV))):    # beyond 2.5 m; PARTIAL
        far = perceive(params, [(ROBOT, x, y, math.pi, -1, False)], 5000).detections
        assert not (far["true_id"] == -1).any(), (x, y)


# ---- rule 1: position errors ----------------------------------------------------------------------------------------
@pytest.mark.parametrize("cls,distance,magnitude", [(BALL, 0.5, 1.0), (BALL, 1.0, 1.0), (BALL, 2.0, 1.0),
                                                    (BALL, 3.0, 1.0), (BALL, 5.0, 1.0), (ROBOT, 3.0, 2.0)])
def test_realistic_position_error_grows_with_the_square_of_distance(cls, distance, magnitude):
    """docs "Error model", realistic polar: radial σ = m·(0.01 + 0.0175·d²) m, bearing σ = m·0.0175 rad, unbiased
    (docs table: "0.01 m + 0.0175·d² radial, 1° bearing"; config/perception/realistic.yaml position)."""
    rows = perceive(load_preset("realistic", noise_magnitude=magnitude), [(cls, distance, 0.0, 0.0, -1, False)],
                    20000).detections
    rows = rows[rows["true_id"] == 1]
    x, y = rows["x"].astype(float), rows["y"].astype(float)
    assert_normal(np.hypot(x, y) - distance, 0.0, magnitude * (0.01 + 0.0175 * distance ** 2), "radial error")
    assert_normal(np.arctan2(y, x), 0.0, magnitude * 0.0175, "bearing error")


def test_random_mode_position_error_is_the_same_at_every_distance():
    """docs "Error model", random, polar: σ = magnitude·random_std per axis (config/perception/realistic.yaml:
    random_std 0.05)."""
    params = load_preset("realistic", mode="random", noise_magnitude=2.0)
    for distance in (1.0, 4.0):
        rows = perceive(params, [(BALL, distance, 0.0, np.nan, 0, False)], 20000).detections
        rows = rows[rows["true_id"] == 1]
        assert_normal(rows["x"].astype(float) - distance, 0.0, 2.0 * 0.05, f"x at {distance} m")
        assert_normal(rows["y"].astype(float), 0.0, 2.0 * 0.05, f"y at {distance} m")


@pytest.mark.parametrize("distance,magnitude,mode", [(1.0, 1.0, "realistic"), (2.0, 1.0, "realistic"),
                                                     (3.5, 2.0, "realistic"), (6.0, 1.0, "realistic"),
                                                     (2.0, 2.0, "random"), (6.0, 2.0, "random")])
def test_dynenv_position_error_is_uniform_and_sub_centimetre(distance, magnitude, mode):
    """DynEnv: each axis ± 0.5·m·0.0025 m·mult (realistic, mult with near 4.16 m and ×3 DISTANT) or ·4 (random)
    (docs "Error model"; docs/original.md §5.1 "position += n·m·multiplier/4" px, RANDOM "at most ±0.5m px per
    axis")."""
    views = 20000
    rows = perceive(load_preset("dynenv", noise_magnitude=magnitude, mode=mode),
                    [(BALL, distance, 0.0, np.nan, 0, False)], views).detections
    rows = rows[rows["true_id"] == 1]
    mult = multiplier(distance, 4.16, "distant" if distance > 4.16 else None) if mode == "realistic" else 4.0
    bound = 0.5 * magnitude * 0.0025 * mult
    for err in (rows["x"].astype(float) - distance, rows["y"].astype(float)):
        assert np.abs(err).max() >= bound * 0.99                          # P(all inside 0.99·bound) = 0.99^n
        assert_uniform(err, -bound, bound, "error per axis")            # within float32 rounding (1e-6 m)
    if distance <= 4.16 and magnitude == 1.0:
        assert bound < 0.01                          # docs/original.md §5.1: "usually below 1 px = 1 cm"


@pytest.mark.parametrize("preset,magnitude", [("realistic", 1.0), ("dynenv", 2.0)])
def test_line_endpoints_get_the_position_error_of_their_own_distance(preset, magnitude):
    """docs: "lines' endpoints get the position error of their own distance". Realistic: the polar error of each
    endpoint's distance; DynEnv: endpoint i ± 0.0025·m·mult_i per axis (docs/original.md §5.1 "endpoint i +=
    n·m·mult_i/2" px, mult_i with 832 px). Endpoints are reported nearer first."""
    views = 20000
    near, far = (2.0, -0.5), (3.5, 0.5)
    result = perceive(load_preset(preset, noise_magnitude=magnitude), [], views, lines=[(*far, *near)])
    rows = result.detections[result.detections["class_id"] == LINE]
    for (tx, ty), (kx, ky) in ((near, ("line_start_x", "line_start_y")), (far, ("line_end_x", "line_end_y"))):
        x, y, d = rows[kx].astype(float), rows[ky].astype(float), math.hypot(tx, ty)
        if preset == "realistic":
            assert_normal(np.hypot(x, y) - d, 0.0, magnitude * (0.01 + 0.0175 * d ** 2), f"radial at {d:.2f} m")
            assert_normal(np.arctan2(y, x) - math.atan2(ty, tx), 0.0, magnitude * 0.0175, f"bearing at {d:.2f} m")
        else:
            bound = 0.0025 * magnitude * multiplier(d, 8.32)
            assert_uniform(x - tx, -bound, bound, f"x at {d:.2f} m")
            assert_uniform(y - ty, -bound, bound, f"y at {d:.2f} m")


@pytest.mark.parametrize("preset,size_std,yaw_std", [("realistic", 0.05, 0.15), ("dynenv", 0.058, 0.0)])
def test_size_and_heading_errors(preset, size_std, yaw_std):
    """docs: "Sizes get a relative error σ = magnitude·size_std; robots' headings σ = magnitude·yaw_std"; docs
    table "size_std, yaw_std | 0.058, 0 | 0.05, 0.15 rad" (DynEnv: size × (1 ± 0.1) uniform, σ 0.2/√12 ≈ 0.058)."""
    magnitude = 2.0
    rows = perceive(load_preset(preset, noise_magnitude=magnitude), [(ROBOT, 2.0, 0.0, 0.7, -1, False)],
                    20000).detections
    rows = rows[(rows["true_id"] == 1) & (rows["class_id"] == ROBOT)]
    assert_normal(rows["size_x"] / SIZE[ROBOT], 1.0, magnitude * size_std, "relative size")
    np.testing.assert_allclose(rows["size_y"], rows["size_x"])
    if yaw_std:
        assert_normal(rows["yaw"].astype(float), 0.7, magnitude * yaw_std, "heading")
    else:
        np.testing.assert_allclose(rows["yaw"], 0.7, atol=1e-6)


# ---- magnitude 0, determinism, state, lines, parameters -------------------------------------------------------------
def test_noise_magnitude_zero_reports_exactly_what_is_visible():
    params = load_preset("realistic", noise_magnitude=0.0)
    objects = [(BALL, 2.0, 0.3, np.nan, 0, False), (ROBOT, 3.0, -0.8, 1.0, -1, True),
               (POST, 4.0, 1.0, np.nan, 0, False)]
    result = perceive(params, objects, 500)
    assert len(result.detections) == 500 * 3 and result.seen[:, 1:].all()
    rows = result.of_view(0)
    by_id = {int(r["true_id"]): r for r in rows}
    for i, (cls, x, y, _yaw, _team, _fallen) in enumerate(objects, start=1):
        assert by_id[i]["class_id"] == cls and by_id[i]["x"] == pytest.approx(x) and by_id[i]["y"] == pytest.approx(y)
    robot = by_id[2]
    assert robot["yaw"] == pytest.approx(1.0) and robot["team"] == -1 and robot["fallen"]


def test_memory_grows_linearly_with_the_number_of_views():
    """A Perceiver perceives thousands of views in one call (docs: "all robots and all 5 frames of a period are
    computed as one set of arrays"): its peak memory for 4× the views is well under the 16× of an all-pairs table."""
    import tracemalloc
    objects = [(BALL, 2.0, 0.3, np.nan, 0, False), (ROBOT, 3.0, -0.5, 0.0, -1, False),
               (POST, 4.0, 1.0, np.nan, 0, False)]
    peaks = []
    for views in (500, 2000):
        obj, frames, v = scene(objects, views, lines=[(2.5, -6.0, 2.9, 7.0)])
        perceiver = Perceiver(obj, load_preset("realistic", noise_magnitude=2.0))
        tracemalloc.start()
        try:
            perceiver.perceive(frames, v, np.random.default_rng(0), np.ones(views, np.int8))
            peaks.append(tracemalloc.get_traced_memory()[1])
        finally:
            tracemalloc.stop()
    assert peaks[1] < 6 * peaks[0], f"peak {peaks[0] / 1e6:.1f} MB for 500 views, {peaks[1] / 1e6:.1f} MB for 2000"


def test_same_seed_same_detections_other_seed_other_detections():
    params = load_preset("realistic", noise_magnitude=2.0)
    objects = [(BALL, 2.0, 0.3, np.nan, 0, False), (ROBOT, 3.0, -0.8, 1.0, -1, False)]
    a, b, c = (perceive(params, objects, 200, seed=s, lines=[(2.0, -3.0, 4.0, 1.0)]) for s in (5, 5, 6))
    assert a.detections.tobytes() == b.detections.tobytes()
    assert a.detections.tobytes() != c.detections.tobytes()


def test_the_observed_robots_own_state_is_reported_not_the_observers():
    """docs/original.md §12.2: DynEnv reported the observer's fallen flag; docs: robots carry the team relation
    (own/opponent)."""
    params = load_preset("none")
    obj, frames, views = scene([(ROBOT, 2.0, 0.0, 0.0, 1, False)])
    frames.fallen[0, 0] = True                      # the observer is fallen, the observed robot is not
    for observer_team, relation in ((1, 1), (-1, -1)):      # the observed robot is of team +1
        rows = Perceiver(obj, params).perceive(frames, views, np.random.default_rng(0),
                                               np.full(1, observer_team, np.int8)).of_view(0)
        assert not rows["fallen"][0] and rows["team"][0] == relation


def test_a_line_is_clipped_to_the_view_and_reported_by_its_closest_point():
    params = load_preset("none")
    rows = perceive(params, [], lines=[(2.0, -10.0, 2.0, 10.0)]).of_view(0)
    assert len(rows) == 1 and rows["class_id"][0] == LINE
    ends = sorted([(rows["line_start_x"][0], rows["line_start_y"][0]), (rows["line_end_x"][0], rows["line_end_y"][0])],
                  key=lambda p: p[1])
    assert ends[0] == pytest.approx((2.0, -2.0 * math.tan(HALF_FOV)), abs=1e-5)
    assert ends[1] == pytest.approx((2.0, 2.0 * math.tan(HALF_FOV)), abs=1e-5)
    assert (rows["x"][0], rows["y"][0]) == pytest.approx((2.0, 0.0), abs=1e-5)
    assert abs(rows["yaw"][0]) == pytest.approx(math.pi / 2, abs=1e-5)
    assert rows["sighting"][0] & Sighting.PARTIAL
    assert len(perceive(params, [], lines=[(-2.0, -10.0, -2.0, 10.0)]).of_view(0)) == 0   # behind the camera


@pytest.mark.parametrize("values,message", [
    ({"mode": "sloppy"}, "mode"), ({"noise_magnitude": 6}, "noise_magnitude"), ({"colour": 1}, "unknown"),
    ({"classes": {"dragon": {"near_range": 1.0, "max_range": 2.0}}}, "unknown class"),
    ({"miss": {"base": -0.1}}, "base"), ({"miss": {"basis": 0.1}}, "unknown setting"),
    ({"field_of_view": 4.0}, "field_of_view"), ({"confusions": [{"source": "ball", "target": "kite",
                                                                 "probability": 1}]}, "unknown class"),
    ({"confidence": "reliability"}, "confidence"), ({"occlusion": {"model": "wedge"}}, "occlusion.model"),
    ({"position": {"model": "gaussian"}}, "position.model"), ({"confidence_separation": -1.0}, "confidence_separation"),
    ({"confidence_separation": "high"}, "confidence_separation"),
    ({"classes": {**{name: {"near_range": 1.0, "max_range": 2.0} for name in (
        "robot", "goalpost", "penalty_cross", "line_crossing", "field_line", "center_circle")},
        "ball": {"near_range": 3.0, "max_range": 6.0, "correct_prior": 1.0}}}, "correct_prior")])
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
