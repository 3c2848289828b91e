"""``perceive``: every view's detections for one batch of vision frames — the perception error model.

Geometry first (field of view, range, occlusion, clipping), then the error model of the chosen mode:
``realistic`` implements the paper's four rules — (1) misses and position errors grow with distance, (2) misses are
likelier for objects close together and at the edge of the view, (3) similar classes are confused, (4) false
positives appear in likely places (balls at robots' feet) and uniformly in the view; ``random`` uses fixed
probabilities; ``none`` reports exactly what is visible. All views are computed as one set of arrays.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from types import ModuleType
from typing import Any, cast

import numpy as np

from dynenv_ros.core.object_classes import ObjectClass, Sighting
from dynenv_ros.perception.detections import DETECTION_DTYPE
from dynenv_ros.perception.params import PerceptionParams
from dynenv_ros.perception.scene import SceneFrames, SceneObjects, Views

LANDMARK_CLASSES = (ObjectClass.GOALPOST, ObjectClass.PENALTY_CROSS, ObjectClass.LINE_CROSSING)
NOMINAL_SIZE = {ObjectClass.BALL: 0.1, ObjectClass.ROBOT: 0.2, ObjectClass.GOALPOST: 0.1,
                ObjectClass.PENALTY_CROSS: 0.1, ObjectClass.LINE_CROSSING: 0.1}
_NOMINAL_SIZES = np.full(256, 0.1)
for _cls, _size in NOMINAL_SIZE.items():
    _NOMINAL_SIZES[_cls] = _size
# Plain ints for the hot paths: comparing an array with an IntEnum member costs several µs more than with an int.
_UNKNOWN, _BALL, _ROBOT = int(ObjectClass.UNKNOWN), int(ObjectClass.BALL), int(ObjectClass.ROBOT)
_FIELD_LINE, _CENTER_CIRCLE = int(ObjectClass.FIELD_LINE), int(ObjectClass.CENTER_CIRCLE)
_DISTANT, _PARTIAL, _NEARBY = int(Sighting.DISTANT), int(Sighting.PARTIAL), int(Sighting.NEARBY)
CIRCLE_SAMPLES = 36
MIN_LINE_LENGTH = 0.1        # m of a line that must be in view to detect it
_EPS = 1e-9
_IDENTITY = np.arange(256, dtype=np.uint8)      # a confusion target table that confuses nothing
_Part = tuple[np.ndarray, np.ndarray]      # detection rows and each row's view


@dataclass
class Perception:
    """Detections of all views, concatenated in view order; ``of_view(v)`` is a slice (no copy)."""
    detections: np.ndarray           # structured DETECTION_DTYPE, views one after another
    offsets: np.ndarray              # (V + 1,) start of each view's rows
    seen: np.ndarray                 # (V, N) bool: object truly detected as its own class (before false positives)
    lines_seen: np.ndarray           # (V,) int: field lines truly detected
    visible: np.ndarray              # (V, N) bool: geometrically visible (in view, in range, not hidden)

    def of_view(self, view: int) -> np.ndarray:
        return self.detections[self.offsets[view]:self.offsets[view + 1]]

    def __len__(self) -> int:
        return len(self.offsets) - 1


def _kernels() -> ModuleType:
    """The compiled kernels (``soccer_kernels``), imported and compiled (or loaded from numba's cache) on the first
    ``Perceiver``: importing numba costs ≈ 1 s and ≈ 80 MB, which the physics-and-rules path never pays."""
    global _KERNELS
    if _KERNELS is None:
        from dynenv_ros.perception import soccer_kernels
        soccer_kernels.warm_up()
        _KERNELS = soccer_kernels
    return _KERNELS


_KERNELS: ModuleType | None = None


def missed_objects(visible: np.ndarray, detections: np.ndarray, object_ids: np.ndarray) -> np.ndarray:
    """(N,) bool: objects geometrically visible in a view that no detection row comes from. A confused object
    has a row (with the wrong class), so it counts as detected here, not as missed."""
    return np.asarray(visible, bool) & ~np.isin(object_ids, np.asarray(detections)["true_id"])


class Perceiver:
    """Per-class tables for one scene and one parameter set, so ``perceive`` only does per-frame work."""

    def __init__(self, objects: SceneObjects, params: PerceptionParams) -> None:
        self.objects = objects
        self.params = params
        self._kernels = _kernels()
        cls = objects.class_id
        table = params.classes
        # Per class id (what a report of that class gets), and per scene object (what the object itself gets).
        self.class_near, self.class_max = np.full(256, np.inf), np.full(256, np.inf)
        self.class_miss_scale, self.class_reach_radius = np.ones(256), np.zeros(256)
        self.class_prior_logit = np.zeros(256)
        for c, cp in table.items():
            self.class_near[c], self.class_max[c] = cp.near_range, cp.max_range
            self.class_miss_scale[c], self.class_reach_radius[c] = cp.miss_scale, cp.visibility_radius
            self.class_prior_logit[c] = math.log(cp.correct_prior / (1.0 - cp.correct_prior))
        self.near, self.max_range = self.class_near[cls], self.class_max[cls]
        self.miss_scale, self.visibility_radius = self.class_miss_scale[cls], self.class_reach_radius[cls]
        self.is_robot = cls == ObjectClass.ROBOT
        self.is_landmark = np.isin(cls, LANDMARK_CLASSES)
        self.occluder_index = np.flatnonzero(objects.occluder)
        self.dynamic_index = np.flatnonzero(objects.dynamic)
        line = table[ObjectClass.FIELD_LINE]
        self.line_near, self.line_max, self.line_scale = line.near_range, line.max_range, line.miss_scale
        lines = np.asarray(objects.lines, float)
        self._line_count = len(lines)
        # Endpoints as (2 coordinates, 2L): first endpoints of all lines, then their second endpoints.
        self._lines = lines
        half = params.field_of_view / 2
        self._half_sin, self._half_cos = math.sin(half), math.cos(half)
        # A circle (soccer's centre circle) is a point object whose visibility is decided by its rim.
        circles = np.flatnonzero(cls == ObjectClass.CENTER_CIRCLE)
        self.circle_index = int(circles[0]) if len(circles) else None
        if self.circle_index is not None:
            angles = np.linspace(0.0, 2 * math.pi, CIRCLE_SAMPLES, endpoint=False)
            self.rim_offsets = objects.size_x[self.circle_index] / 2 * np.column_stack((np.cos(angles),
                                                                                         np.sin(angles)))
            self.occluder_index = self.occluder_index[self.occluder_index != self.circle_index]
        self._fp_classes = np.asarray(params.false_positives.classes, np.uint8)
        self.robot_index = np.flatnonzero(self.is_robot)
        self._robots_before = np.searchsorted(self.robot_index, np.arange(len(cls)))   # per object index
        # What a made-up report (false positive, confusion) of a class looks like: the size of the scene's objects
        # of that class (a class the scene lacks: its nominal size), and their subtype — the one the class always
        # has, or (crossings: L, T, X) a random real one's.
        self.class_size = _NOMINAL_SIZES.copy()
        self._class_subtype = np.zeros(256, np.uint8)
        self._varied_subtypes: dict[int, np.ndarray] = {}
        for c in np.unique(cls):
            members = cls == c
            self.class_size[c] = objects.size_x[members][0]
            subtypes = objects.subtype[members]
            if c != ObjectClass.ROBOT and (subtypes != subtypes[0]).any():
                self._varied_subtypes[int(c)] = subtypes.copy()
            else:
                self._class_subtype[c] = subtypes[0]
        # Confusion rules as arrays: source class, target class, probability, distant only.
        self.confusions = [(int(c.source), int(c.target), c.probability, c.distant_only) for c in params.confusions]
        # Rules with distinct sources as tables: probability·ρ per reported class (+256: when DISTANT), target.
        self._confusion_rate: np.ndarray | None = None
        if len({source for source, *_ in self.confusions}) == len(self.confusions):
            self._confusion_rate, self._confusion_target = np.zeros(512), np.arange(256, dtype=np.uint8)
            for source, target, probability, distant_only in self.confusions:
                rate = probability * params.rho
                self._confusion_rate[source + 256], self._confusion_target[source] = rate, target
                if not distant_only:
                    self._confusion_rate[source] = rate
        # The miss multiplier's sighting factor per sighting bits: PARTIAL, else DISTANT, else NEARBY.
        miss = params.miss
        self._sighting_factor = np.array([miss.partial_factor if b & _PARTIAL else miss.distant_factor
                                          if b & _DISTANT else miss.nearby_factor if b & _NEARBY else 1.0
                                          for b in range(8)])
        self._point_class = np.ones(256, bool)          # reports that get their sighting bits from themselves
        self._point_class[[_FIELD_LINE, _CENTER_CIRCLE]] = False
        self._dynamic_class = np.zeros(256, bool)       # reports that make their neighbours NEARBY
        self._dynamic_class[[_BALL, _ROBOT]] = True
        fp = params.false_positives
        self._fp_probability = min(1.0, fp.probability * params.noise_magnitude)
        self._fp_none = bool((self._fp_classes == _UNKNOWN).any())
        self._fp_range = np.minimum(fp.max_distance, self.class_max)      # per class
        self._fp_floor = np.maximum(2 * self.class_reach_radius, _EPS)
        self._n = len(cls)
        self._layouts: dict[tuple[bytes, bytes], _Layout] = {}

    def leave_out(self, objects: np.ndarray | list[int]) -> None:
        """Objects that are not in the scene (soccer's robots out of play for an episode): never in view, so never
        detected, seen or made up at their place, and never hiding or crowding another object. Their views, if they
        observe, are still computed."""
        index = np.asarray(objects, np.intp)
        self.max_range = self.max_range.copy()
        self.max_range[index] = -1.0                       # no distance is within it
        self.occluder_index = np.setdiff1d(self.occluder_index, index)
        self.dynamic_index = np.setdiff1d(self.dynamic_index, index)
        self._layouts.clear()                              # the index tables are built from the three above

    # ------------------------------------------------------------------------------------------------------------
    def perceive(self, frames: SceneFrames, views: Views, rng: np.random.Generator,
                 observer_team: np.ndarray) -> Perception:
        """Detections for every view. ``observer_team`` (V,) is each observer's absolute team.

        Every (view, object) pair is one entry of flat arrays (pair v·N + j, see ``_Layout``): the arrays are small,
        so numpy's cost is per call and per inner loop, and long contiguous arrays keep both few."""
        p = self.params
        lay = self._layout(views)
        V, N = len(lay.observer_source), self._n
        fx, fy = frames.x.ravel(), frames.y.ravel()
        src, pv = lay.pair_source, lay.pair_view
        kern = self._kernels
        heading = frames.yaw.ravel()[lay.observer_source] + views.head_yaw  # camera heading (V,)
        ch, sh = np.cos(heading), np.sin(heading)
        cx, cy = kern.camera_offsets(fx, fy, src, lay.observer_of_pair, pv, ch, sh)    # camera frame
        d = np.hypot(cx, cy)
        bearing = np.arctan2(cy, cx)
        half = p.field_of_view / 2
        # (the radius over the distance is never negative: no lower clamp)
        reach = np.arcsin(kern.reach_ratio(lay.visibility_radius, d))
        in_view, partial = kern.in_view_partial(bearing, reach, d, lay.max_range, half, lay.own_pair)
        if self.circle_index is not None:                  # the circle: seen when enough of its rim is in view
            circle = lay.circle_pair
            rim_count = self._circle_rim_in_view(lay, fx, fy, ch, sh)
            in_view[circle] = rim_count >= 3
            partial[circle] = rim_count < CIRCLE_SAMPLES
        # From here on, only the pairs in view: 1-D arrays of candidates, then of the K visible pairs.
        at = in_view.nonzero()[0]
        j = lay.pair_object[at]
        if p.occlusion.enabled and len(self.occluder_index):
            hidden = self._hidden(lay, at, j, cx, cy, d, bearing, in_view)
        else:
            hidden = np.zeros(len(at), bool)
        # The visible pairs (the circle is painted on the floor: never hidden), their distance, class, the class's
        # near range, DISTANT, the sighting bits the report gets from geometry (PARTIAL, DISTANT), camera position.
        circle_index = -1 if self.circle_index is None else self.circle_index
        at, j, v, dk, ck, near, distant_k, bits, xk, yk, visible = kern.visible_pairs(
            at, j, hidden, circle_index, pv, d, partial, cx, cy, self.objects.class_id, self.near, V * N, 1, _PARTIAL)
        K = len(at)
        reported = ck
        extra = []
        if p.mode == "none" or p.noise_magnitude <= 0.0:
            confused, keep = np.zeros(K, bool), np.ones(K, bool)
            size_factor, yaw_noise = np.ones(K), np.zeros(K)
        else:
            m, rho = p.noise_magnitude, p.rho
            realistic = p.mode == "realistic"
            if realistic and (self._confusion_rate is not None or not self.confusions):
                # Rules 1–3 in one compiled pass (the code below, for the realistic mode with table confusions).
                u = rng.random((4, K))
                confusion_rate = self._confusion_rate if self._confusion_rate is not None else np.zeros(512)
                mult, keep, reported, confused = kern.realistic_misses(
                    fx, fy, lay.close_first, lay.close_second, lay.close_self, len(frames.x), len(self.dynamic_index),
                    N, src, lay.observer_closeness, at, j, bits, dk, near, ck, distant_k, circle_index,
                    self._sighting_factor, _NEARBY, p.miss.range_offset, p.miss.range_slope,
                    p.miss.nearby_distance ** 2, self.miss_scale, rho, u, self._confusion_rate is not None,
                    confusion_rate, self._confusion_target if self._confusion_rate is not None else _IDENTITY)
            else:
                if realistic:
                    nearby_k = self._nearby(frames, lay, at)
                    if self.circle_index is not None:          # painted on the floor: never crowded
                        nearby_k &= j != self.circle_index
                    factor = self._sighting_factor[bits + nearby_k * _NEARBY]   # partial, else distant, else nearby
                    mult = (p.miss.range_offset + p.miss.range_slope * (dk / near) ** 2) * factor
                else:
                    mult = np.ones(K)
                u = rng.random((4, K))
                p_miss = np.minimum(1.0, rho * self.miss_scale[j] * mult)
                keep = u[0] >= p_miss
                if realistic and self.confusions:
                    reported, confused = self._confuse(ck, distant_k, keep, mult, u[1])
                else:
                    confused = np.zeros(K, bool)
            xk, yk, g = self._position_noise(xk, yk, dk, mult, rng)
            fp = p.false_positives
            size_factor, yaw_noise, at_feet, kept_now = kern.feet_and_errors(
                ck, reported, keep, dk, bits, u, g, m, p.position.size_std, p.position.yaw_std, realistic,
                fp.at_feet_range, fp.at_feet_probability, fp.at_feet_robot_dropped, _ROBOT)
            if len(at_feet):
                extra.append(self._feet_balls(v[at_feet], xk[at_feet], yk[at_feet], rng))
                keep = kept_now
        context = _ViewContext(lay.frame, lay.observer, heading, frames, observer_team, N)
        # The kept reports' rows (``soccer_kernels.point_rows``, one compiled pass), with the geometric sighting bits: the circle
        # keeps those of its rim test (every other point report gets them from the report itself, in _assemble).
        obj = self.objects
        real, real_views, confused_rows, confused_views, seen = kern.point_rows(
            keep, confused, at, v, j, src, reported, xk, yk, size_factor, yaw_noise, bits, frames.yaw.ravel(),
            heading, observer_team, frames.fallen.ravel(), frames.penalized.ravel(), obj.size_x, obj.size_y,
            obj.team, obj.subtype, obj.object_id, obj.class_id, _ROBOT, V * N)
        point_rows = (real, real_views)
        line_rows, lines_seen = self._line_rows(lay, fx[lay.observer_source], fy[lay.observer_source], ch, sh, rng)
        rows = [line_rows]
        if p.mode != "none" and p.noise_magnitude > 0.0:
            # Reports no object of their class stands behind: confusions, balls at feet, uniform false positives.
            made_up = [(confused_rows, confused_views)] + extra
            made_up.append(self._false_positives(lay, rng))
            rows.append(self._made_up_rows(_concatenate(made_up), context, rng))
        rows.append(point_rows)
        return self._assemble(rows, lay, seen.reshape(V, N), lines_seen, visible.reshape(V, N), rng)

    def _layout(self, views: Views) -> "_Layout":
        """The index tables of these views, built on first use and kept (a caller's views rarely change)."""
        frame, observer = np.asarray(views.frame, np.intp), np.asarray(views.observer, np.intp)
        key = (frame.tobytes(), observer.tobytes())
        layout = self._layouts.get(key)
        if layout is None:
            if len(self._layouts) >= 16:
                self._layouts.clear()
            layout = self._layouts[key] = _Layout.build(self, frame, observer)
        return layout

    def _hidden(self, lay: "_Layout", at: np.ndarray, j: np.ndarray, cx: np.ndarray, cy: np.ndarray,
                d: np.ndarray, bearing: np.ndarray, in_view: np.ndarray) -> np.ndarray:
        """(C,) for the candidate pairs ``at`` (objects ``j``): behind a robot, in its shadow cone (``cone``) or
        within the occluder radius of the sight line through it (``band``, DynEnv's rule, where only robots in the
        field of view occlude). Occluder quantities are (occluders, views), gathered per candidate's view."""
        occlusion = self.params.occlusion
        hidden: np.ndarray = self._kernels.hidden(at, j, lay.pair_view, cx, cy, d, bearing, in_view, lay.occluder_pair,
                                    lay.occluder_not_observer, lay.occluder_object.ravel(),
                                    occlusion.model == "band", occlusion.occluder_radius)
        return hidden

    def _nearby(self, frames: SceneFrames, lay: "_Layout", at: np.ndarray) -> np.ndarray:
        """For the pairs ``at``: another moving object (not the observer) within ``nearby_distance`` of the object.
        Closeness is a property of the frame, so it is found per frame and each view only discounts its observer."""
        k = self.dynamic_index
        if not len(k):
            return np.zeros(len(at), bool)
        X, Y = frames.x.ravel(), frames.y.ravel()
        first, second = lay.close_first, lay.close_second
        ddx, ddy = X[first] - X[second], Y[first] - Y[second]
        F, N = len(frames.x), self._n
        close = np.zeros((F, len(k) + 1, N), bool)                       # (F, dynamic + a row of none, N)
        np.less((ddx * ddx + ddy * ddy).reshape(F, len(k), N), self.params.miss.nearby_distance ** 2,
                out=close[:, :-1])
        close.ravel()[lay.close_self] = False                             # an object is not its own neighbour
        count = close.sum(axis=1)                                         # (F, N)
        nearby: np.ndarray = count.ravel()[lay.pair_source[at]] > close.ravel()[lay.observer_closeness[at]]
        return nearby

    def _confuse(self, cls: np.ndarray, distant: np.ndarray, keep: np.ndarray, mult: np.ndarray,
                 u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Rule 3: (reported class, confused) after the confusion rules, drawing on ``u``. Rules with distinct
        sources cannot compete for a report, so they run as one table lookup; otherwise in order."""
        if self._confusion_rate is not None:
            hit = keep & (u < self._confusion_rate[cls + distant * 256] * mult)
            return np.where(hit, self._confusion_target[cls], cls), hit
        reported, confused = cls.copy(), np.zeros(len(cls), bool)
        rho = self.params.rho
        for source, target, probability, distant_only in self.confusions:
            rule = (reported == source) & ~confused & keep
            if distant_only:
                rule &= distant
            hit = rule & (u < probability * rho * mult)
            reported[hit] = target
            confused |= hit
        return reported, confused

    def _position_noise(self, x: np.ndarray, y: np.ndarray, d: np.ndarray, mult: np.ndarray,
                        rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Noisy positions, and the (2, n) standard normals of the size and yaw errors, which come next in the
        draw order (polar model: drawn in the same call)."""
        p, m = self.params.position, self.params.noise_magnitude
        if p.model == "uniform":
            scale = m * p.uniform_scale * (mult if self.params.mode == "realistic" else 4.0)
            u = rng.random((2,) + x.shape) - 0.5
            return x + u[0] * scale, y + u[1] * scale, rng.standard_normal((2,) + x.shape)
        g = rng.standard_normal((4,) + x.shape)
        noisy = self._polar_point_noise(np.array((x, y)), g[:2], d)
        return noisy[0], noisy[1], g[2:]

    def _made_up_rows(self, part: _Part, context: "_ViewContext", rng: np.random.Generator) -> _Part:
        """Give reports that no object of their class stands behind (false positives, confusions) the attributes
        a real detection of that class has: its class's size with the same size error, and for robots the heading,
        team and state of a randomly chosen other robot of the game (so neither the marginal team mix nor the
        fallen rate differs), for crossings the shape of a randomly chosen real crossing."""
        rows, v = part
        n = len(rows)
        if n == 0:
            return part
        p = self.params
        cls = rows["class_id"]
        g = rng.standard_normal((2, n))
        m = p.noise_magnitude
        robot = (cls == _ROBOT).nonzero()[0]
        others = self.robot_index
        if len(others) > 1:                              # another robot for every observer: one compiled pass
            picks = rng.random(len(robot)) if len(robot) else np.zeros(0)
            frames = context.frames
            self._kernels.dress_made_up(rows, v, g, m, p.position.size_std, p.position.yaw_std, self.class_size,
                                        self._class_subtype, _ROBOT, robot, picks, context.observer, context.frame,
                                        context.heading, context.observer_team, self.is_robot, self._robots_before,
                                        others, frames.yaw.ravel(), frames.fallen.ravel(), frames.penalized.ravel(),
                                        self.objects.team, context.objects)
            self._varied_subtype_draws(rows, cls, rng)
            return rows, v
        factor = np.maximum(0.2, 1.0 + m * p.position.size_std * g[0])
        rows["size_x"] = rows["size_y"] = self.class_size[cls] * factor
        rows["yaw"] = np.nan
        rows["team"] = 0
        rows["fallen"] = rows["penalized"] = False
        rows["subtype"] = self._class_subtype[cls]
        if len(robot):
            view = v[robot]
            observer = context.observer[view]
            observer_is_robot = self.is_robot[observer]
            choices = len(others) - observer_is_robot
            if len(others) > 1 or len(others) and (choices > 0).all():   # (two robots: always another one)
                pick = (rng.random(len(robot)) * choices).astype(np.intp)
                pick += observer_is_robot & (pick >= self._robots_before[observer])
                r = others[pick]
                src = context.frame[view] * context.objects + r
                frames = context.frames
                rows["yaw"][robot] = _wrap(frames.yaw.ravel()[src] - context.heading[view]
                                           + m * p.position.yaw_std * g[1, robot])
                rows["team"][robot] = self.objects.team[r] * context.observer_team[view]
                rows["fallen"][robot] = frames.fallen.ravel()[src]
                rows["penalized"][robot] = frames.penalized.ravel()[src]
            else:                                        # no other robot to resemble: a plausible stranger
                rows["yaw"][robot] = (rng.random(len(robot)) * 2 - 1) * math.pi
                rows["team"][robot] = np.where(rng.random(len(robot)) < 0.5, -1, 1)
        self._varied_subtype_draws(rows, cls, rng)
        return rows, v

    def _varied_subtype_draws(self, rows: np.ndarray, cls: np.ndarray, rng: np.random.Generator) -> None:
        """Made-up reports of a class whose objects differ in subtype (crossings: L, T, X) get a random real one's."""
        for c, subtypes in self._varied_subtypes.items():
            at = (cls == c).nonzero()[0]
            if len(at):
                rows["subtype"][at] = subtypes[(rng.random(len(at)) * len(subtypes)).astype(np.intp)]

    def _feet_balls(self, v: np.ndarray, rx: np.ndarray, ry: np.ndarray, rng: np.random.Generator) -> _Part:
        """Rule 4: a ball seen at the feet of a nearby robot (DynEnv: 10ρ per robot within 2.5 m)."""
        rows = np.zeros(len(v), DETECTION_DTYPE)
        rows["yaw"] = np.nan
        rows["true_id"] = -1
        rows["class_id"] = _BALL
        spread = self.params.false_positives.at_feet_spread
        dist = np.maximum(np.hypot(rx, ry), _EPS)
        toward = 0.1 + spread * rng.random(len(v))                        # in front of the feet, observer's side
        side = spread * (rng.random(len(v)) * 2 - 1)
        rows["x"] = rx - rx / dist * toward - ry / dist * side
        rows["y"] = ry - ry / dist * toward + rx / dist * side
        return rows, v

    def _false_positives(self, lay: "_Layout", rng: np.random.Generator) -> _Part:
        """Rule 4, uniform part: ``trials`` chances per frame, anywhere a detection of the drawn class could be —
        uniform in distance up to ``max_distance`` (and the class's range), uniform in bearing across the view
        widened by the class's reach asin(radius / max(distance, 2·radius)), as partially seen real objects are."""
        counts = rng.binomial(self.params.false_positives.trials, self._fp_probability, size=len(lay.views))
        chances = int(counts.sum())
        if not chances:
            return np.zeros(0, DETECTION_DTYPE), np.zeros(0, np.int64)
        u = rng.random((3, chances))                                      # every draw at once
        kern = self._kernels
        # Per chance its class ("none" drawn: no report); per report its view, class, distance u₁·range and the
        # sine of its reach, radius / max(distance, floor) within [0, 1] (at most 30°: nothing stands closer than
        # its size); numpy's arcsin, cos and sin between the compiled passes.
        v, classes, r, ratio, u2 = kern.false_positive_draws(counts, u, self._fp_classes, self._fp_none, _UNKNOWN,
                                                             self._fp_range, self.class_reach_radius, self._fp_floor)
        b = kern.false_positive_bearings(u2, np.arcsin(ratio), self.params.field_of_view / 2)
        return kern.false_positive_rows(classes, r, np.cos(b), np.sin(b)), v

    def _assemble(self, parts: list[_Part], lay: "_Layout", seen: np.ndarray, lines_seen: np.ndarray,
                  visible: np.ndarray, rng: np.random.Generator) -> Perception:
        """All rows of all views, each view's rows nearest first, with the sighting bits and confidences every
        report gets by the same rule whether it is real, confused or false."""
        rows, view = _concatenate(parts)
        # Sorted by view, then distance: one stable sort of (view, the distance's bits), which order as the
        # distance does (never negative).
        distance = np.hypot(rows["x"], rows["y"])
        rows, order, offsets = self._kernels.sort_by_view(rows, view, distance.view(np.uint32), len(lay.views), -1)
        view, distance = view[order], distance[order]
        self._sighting_bits(rows, view, distance)
        self._confidences(rows, rng)
        return Perception(rows, offsets, seen, lines_seen, visible)

    def _sighting_bits(self, rows: np.ndarray, view: np.ndarray, distance: np.ndarray) -> None:
        """DISTANT, PARTIAL and NEARBY of point reports, from the reports themselves — what a real pipeline can
        compute — so no bit tells a false report from a real one: DISTANT beyond the reported class's near range,
        PARTIAL within the class's reach of the view's edge, NEARBY within ``nearby_distance`` of another reported
        ball or robot of the same view (the rows come sorted by view). Lines keep their clipping bits; the circle
        its rim test."""
        kern = self._kernels
        idx, ratio, x, y = kern.sighting_inputs(rows, distance, self._point_class, self.class_reach_radius)
        if len(idx):
            kern.sighting_bits(rows, view, distance, idx, np.arcsin(ratio), np.arctan2(y, x), x, y,
                               self.params.field_of_view / 2, self.class_near, self._dynamic_class,
                               self.params.miss.nearby_distance ** 2, _PARTIAL, _NEARBY)

    def _confidences(self, rows: np.ndarray, rng: np.random.Generator) -> None:
        """Calibrated detector scores. Each report has evidence z ~ N(d', 1) when it is correct (its object exists
        and has its class) and N(0, 1) when it is false or confused; the score is the posterior
        P(correct | z) = sigmoid(logit(prior) + d'·z − d'²/2) under the class's ``correct_prior``. So real and false
        reports overlap as a real detector's do, the score ranks them no better than d' allows (AUC = Φ(d'/√2)),
        and it is calibrated wherever the prior matches the share of correct reports."""
        p = self.params
        if p.confidence == "none":
            rows["confidence"] = 1.0
            return
        minus_logit = self._kernels.confidence_exponents(rows, rng.standard_normal(len(rows)),
                                                         p.confidence_separation, self.class_prior_logit)
        rows["confidence"] = 1.0 / (1.0 + np.exp(minus_logit))

    # -- lines and the centre circle ------------------------------------------------------------------------------
    def _line_rows(self, lay: "_Layout", ox: np.ndarray, oy: np.ndarray, c: np.ndarray, s: np.ndarray,
                   rng: np.random.Generator) -> tuple[_Part, np.ndarray]:
        """Field lines clipped to the view wedge and range; DynEnv's endpoint noise and miss rule.

        Every (view, line endpoint) is one entry of flat arrays (``_Layout.line_view``: all first endpoints, then
        all second ones), and per-view values are gathered, not broadcast: broadcasting a small operand costs a
        numpy inner loop per row."""
        V, L = len(ox), self._line_count
        if L == 0:
            return (np.zeros(0, DETECTION_DTYPE), np.zeros(0, np.int64)), np.zeros(V, int)
        kern, lv = self._kernels, lay.line_view
        # Per (view, line): first end, direction, and the part [lo, hi] inside the view wedge (and range).
        clip = kern.line_clip(lay.line_x, lay.line_y, lv, ox, oy, c, s, self._half_sin, self._half_cos,
                              self.line_max, math.isfinite(self.line_max))
        v, k, ends, bits = kern.line_visible(clip, np.hypot(clip[2], clip[3]), lv, L, MIN_LINE_LENGTH, _PARTIAL)
        K = len(v)
        dist = np.hypot(ends[0], ends[1])                                 # (start/end, pair)
        pr = self.params
        noisy = pr.mode != "none" and pr.noise_magnitude > 0.0
        mult, p_miss = kern.line_miss(dist, bits, self.line_near, pr.mode == "realistic", pr.miss.range_offset,
                                      pr.miss.range_slope, pr.rho * self.line_scale)
        if noisy:
            m = pr.noise_magnitude
            kept = (rng.random(K) >= p_miss).nonzero()[0]
            if pr.position.model == "uniform":
                scale = 2 * m * pr.position.uniform_scale
                u = rng.random((4, K)) - 0.5                              # rows: start x, start y, end x, end y
                ms = mult if pr.mode == "realistic" else 1.0
                ends = ends + u.reshape(2, 2, K).transpose(1, 0, 2) * scale * ms
            else:
                ends = self._polar_point_noise(ends.reshape(2, 2 * K), rng.standard_normal((2, 2 * K)),
                                               dist.reshape(2 * K)).reshape(2, 2, K)
        else:
            kept = np.arange(K)
        # Endpoint order by a rule of the observer's frame alone (nearer end first), so a mirrored or rotated
        # situation gives the mirrored or identical report; an order that follows the field would be a compass.
        # Exact ties (a line square to the gaze, clipped by both edges) go right end first: rotations stay
        # consistent; a perfect tie cannot be mirror-symmetric.
        rows, v, seen, ex, ey = kern.line_rows(ends, np.hypot(ends[0], ends[1]), kept, v, k, bits, V, _FIELD_LINE)
        rows["yaw"] = (np.arctan2(ey, ex) + math.pi / 2) % math.pi - math.pi / 2   # a line has no arrow
        return (rows, v), seen

    def _polar_point_noise(self, xy: np.ndarray, g: np.ndarray, d: np.ndarray) -> np.ndarray:
        """Noisy copies of points ``xy`` (2, n) at distances ``d``: polar errors, or (random mode) per-axis ones,
        from the standard normals ``g`` (2, n)."""
        p, m = self.params.position, self.params.noise_magnitude
        if self.params.mode == "random":
            return xy + g * m * p.random_std
        # r = max(0, d + g₀·m·(base + per_m²·d·d)), b = atan2(y, x) + g₁·m·std; numpy's arctan2, cos and sin.
        r, b = self._kernels.polar_radius_bearing(d, g, np.arctan2(xy[1], xy[0]), m, p.radial_base, p.radial_per_m2,
                                                  p.bearing_std)
        points: np.ndarray = self._kernels.polar_points(r, np.cos(b), np.sin(b))
        return points

    def _circle_rim_in_view(self, lay: "_Layout", fx: np.ndarray, fy: np.ndarray, c: np.ndarray,
                            s: np.ndarray) -> np.ndarray:
        """(V,) how many rim samples of the circle lie in the view wedge and range. (view, sample) entries are
        flat (``_Layout.rim_view``), per-view values gathered."""
        kern = self._kernels
        px, py, in_range = kern.rim_points(fx, fy, lay.rim_circle, lay.rim_observer, lay.rim_x, lay.rim_y,
                                           lay.rim_view, c, s, self.params.classes[ObjectClass.CENTER_CIRCLE].max_range)
        count: np.ndarray = kern.rim_count(np.arctan2(py, px), in_range, self.params.field_of_view / 2, CIRCLE_SAMPLES)
        return count


_RAW = np.dtype((np.void, DETECTION_DTYPE.itemsize))
# Rows as runs of fields (x, y | the line's ends), each written with one numpy call.
_FIELDS = cast(dict[str, tuple[Any, int]], DETECTION_DTYPE.fields)     # (dtype, offset) by name
_ROW_RUNS = np.dtype({"names": ["position", "line"], "formats": [("<f4", (2,)), ("<f4", (4,))],
                      "offsets": [_FIELDS["x"][1], _FIELDS["line_start_x"][1]],
                      "itemsize": DETECTION_DTYPE.itemsize})


def _concatenate(parts: list[_Part]) -> _Part:
    """(rows, views) parts → one (rows, views). As raw records: numpy's structured concatenate re-promotes every
    field (slow for small parts)."""
    rows = np.concatenate([r.view(_RAW) for r, _ in parts]).view(DETECTION_DTYPE)
    return rows, np.concatenate([v for _, v in parts])


def _wrap(angle: np.ndarray) -> np.ndarray:
    return (angle + math.pi) % (2 * math.pi) - math.pi


@dataclass
class _ViewContext:
    """Per view: its frame, observer, camera heading; the frames; each observer's absolute team; the number of
    objects (a row of the frames' arrays)."""
    frame: np.ndarray
    observer: np.ndarray
    heading: np.ndarray
    frames: SceneFrames
    observer_team: np.ndarray
    objects: int


@dataclass
class _Layout:
    """Index tables of one set of views (each view's frame and observer) over the (view, object) pairs, numbered
    v·N + j, so per-pair work runs on flat arrays and per-view or per-object values are gathered, not broadcast."""
    frame: np.ndarray                  # (V,) each view's frame
    observer: np.ndarray               # (V,) each view's observer
    views: np.ndarray                  # (V,) 0..V-1
    view_starts: np.ndarray            # (V + 1,) 0..V
    pair_view: np.ndarray              # (V·N,) v
    pair_object: np.ndarray            # (V·N,) j
    pair_source: np.ndarray            # (V·N,) f·N + j: the pair's object in the frames' flattened (F, N) arrays
    observer_source: np.ndarray        # (V,) f·N + o: each view's observer there
    observer_of_pair: np.ndarray       # (V·N,) the pair's observer there
    own_pair: np.ndarray               # (V,) v·N + o: each observer's own pair
    circle_pair: np.ndarray | None     # (V,) v·N + the circle
    visibility_radius: np.ndarray      # (V·N,) the object's
    max_range: np.ndarray              # (V·N,) the object's
    occluder_pair: np.ndarray          # (K, V) v·N + k for the occluders k
    occluder_object: np.ndarray        # (K, 1) k
    occluder_not_observer: np.ndarray  # (K, V) bool
    observer_closeness: np.ndarray     # (V·N,) index of (f, the observer's row, j) in ``_nearby``'s closeness table
    # ``_nearby``'s (frame, dynamic object k, object j) entries: k's and j's index in the frames' flat arrays,
    # and the entries where k = j.
    close_first: np.ndarray
    close_second: np.ndarray
    close_self: np.ndarray
    # (view, circle rim sample) entries: v, the circle's and the observer's index in the frames' flat arrays, and
    # the sample's offset from the circle's centre.
    rim_view: np.ndarray | None
    rim_circle: np.ndarray | None
    rim_observer: np.ndarray | None
    rim_x: np.ndarray | None
    rim_y: np.ndarray | None
    # (view, line endpoint) entries: all views' first endpoints (v·L + k), then all their second endpoints.
    line_view: np.ndarray              # (2·V·L,) v
    line_x: np.ndarray                 # (2·V·L,) the endpoint's world x
    line_y: np.ndarray                 # (2·V·L,)

    @classmethod
    def build(cls, perceiver: "Perceiver", frame: np.ndarray, observer: np.ndarray) -> "_Layout":
        V, N = len(frame), perceiver._n
        views = np.arange(V)
        v, j = np.repeat(views, N), np.tile(np.arange(N), V)
        observer_source = frame * N + observer
        k = perceiver.occluder_index
        dynamic = perceiver.dynamic_index
        row = np.full(N, len(dynamic))                  # an observer that is not dynamic: the table's empty row
        row[dynamic] = np.arange(len(dynamic))
        circle = perceiver.circle_index
        lines = perceiver._lines
        F, D = int(frame.max(initial=-1)) + 1, len(dynamic)
        f_, k_, j_ = np.meshgrid(np.arange(F), np.arange(D), np.arange(N), indexing="ij")
        close_self = (f_ * (D + 1) + k_) * N + dynamic[k_]
        rim_view: np.ndarray | None = None
        rim_circle: np.ndarray | None = None
        rim_observer: np.ndarray | None = None
        rim_x: np.ndarray | None = None
        rim_y: np.ndarray | None = None
        if circle is not None:
            rim_view = np.repeat(views, CIRCLE_SAMPLES)
            rim_circle, rim_observer = frame[rim_view] * N + circle, observer_source[rim_view]
            rim_x, rim_y = np.tile(perceiver.rim_offsets[:, 0], V), np.tile(perceiver.rim_offsets[:, 1], V)
        return cls(frame=frame, observer=observer, views=views, view_starts=np.arange(V + 1), pair_view=v,
                   pair_object=j, pair_source=frame[v] * N + j, observer_source=observer_source,
                   observer_of_pair=observer_source[v], own_pair=views * N + observer,
                   circle_pair=None if circle is None else views * N + circle,
                   visibility_radius=np.tile(perceiver.visibility_radius, V),
                   max_range=np.tile(perceiver.max_range, V), occluder_pair=views[None, :] * N + k[:, None],
                   occluder_object=k[:, None], occluder_not_observer=k[:, None] != observer[None, :],
                   observer_closeness=(frame[v] * (len(dynamic) + 1) + row[observer[v]]) * N + j,
                   close_first=(f_ * N + dynamic[k_]).ravel(), close_second=(f_ * N + j_).ravel(),
                   close_self=close_self[:, np.arange(D), dynamic].ravel(), rim_view=rim_view,
                   rim_circle=rim_circle, rim_observer=rim_observer, rim_x=rim_x, rim_y=rim_y,
                   line_view=np.tile(np.repeat(views, len(lines)), 2),
                   line_x=np.concatenate((np.tile(lines[:, 0], V), np.tile(lines[:, 2], V))),
                   line_y=np.concatenate((np.tile(lines[:, 1], V), np.tile(lines[:, 3], V))))
