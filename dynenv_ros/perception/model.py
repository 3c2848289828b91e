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

import numpy as np

from dynenv_ros.core.arrays import clamp
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


def missed_objects(visible: np.ndarray, detections: np.ndarray, object_ids: np.ndarray) -> np.ndarray:
    """(N,) bool: objects geometrically visible in a view that no detection row comes from. A confused object
    has a row (with the wrong class), so it counts as detected here, not as missed."""
    return np.asarray(visible, bool) & ~np.isin(object_ids, np.asarray(detections)["true_id"])


class Perceiver:
    """Per-class tables for one scene and one parameter set, so ``perceive`` only does per-frame work."""

    def __init__(self, objects: SceneObjects, params: PerceptionParams) -> None:
        self.objects = objects
        self.params = params
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

    # ------------------------------------------------------------------------------------------------------------
    def perceive(self, frames: SceneFrames, views: Views, rng: np.random.Generator,
                 observer_team: np.ndarray) -> Perception:
        """Detections for every view. ``observer_team`` (V,) is each observer's absolute team."""
        p = self.params
        V, N = len(views), len(self.objects.class_id)
        f, o = views.frame, views.observer
        X, Y = frames.x[f], frames.y[f]                                   # (V, N)
        ox, oy = X[np.arange(V), o][:, None], Y[np.arange(V), o][:, None]
        heading = frames.yaw[f, o] + views.head_yaw                       # camera heading (V,)
        ch, sh = np.cos(heading)[:, None], np.sin(heading)[:, None]
        dx, dy = X - ox, Y - oy
        cx, cy = ch * dx + sh * dy, -sh * dx + ch * dy                    # camera frame
        d = np.hypot(cx, cy)
        bearing = np.arctan2(cy, cx)
        half = p.field_of_view / 2
        reach = np.arcsin(clamp(self.visibility_radius / np.maximum(d, _EPS), 0.0, 1.0))
        off_axis = np.abs(bearing)
        in_view = (off_axis <= half + reach) & (d <= self.max_range)
        partial = off_axis > half - reach
        in_view[np.arange(V), o] = False
        if self.circle_index is not None:                  # the circle: seen when enough of its rim is in view
            rim_count = self._circle_rim_in_view(X[:, self.circle_index], Y[:, self.circle_index], ox[:, 0],
                                                 oy[:, 0], ch[:, 0], sh[:, 0])
            in_view[:, self.circle_index] = rim_count >= 3
            partial[:, self.circle_index] = rim_count < CIRCLE_SAMPLES
        hidden = self._hidden(cx, cy, d, bearing, o, in_view) if p.occlusion.enabled else np.zeros((V, N), bool)
        nearby = self._nearby(frames, f, o)
        if self.circle_index is not None:                  # painted on the floor: never hidden, never crowded
            hidden[:, self.circle_index] = nearby[:, self.circle_index] = False
        visible = in_view & ~hidden
        # From here on, only the visible (view, object) pairs: 1-D arrays of K candidates.
        v, j = np.nonzero(visible)
        dk, ck = d[v, j], self.objects.class_id[j]
        partial_k, distant_k, nearby_k = partial[v, j], dk > self.near[j], nearby[v, j]
        xk, yk = cx[v, j], cy[v, j]
        K = len(v)
        reported = ck.copy()
        confused = np.zeros(K, bool)
        p_miss = np.zeros(K)
        size_factor = np.ones(K)
        yaw_noise = np.zeros(K)
        keep = np.ones(K, bool)
        extra = []
        if p.mode != "none" and p.noise_magnitude > 0.0:
            m, rho = p.noise_magnitude, p.rho
            if p.mode == "realistic":
                mult = (p.miss.range_offset + p.miss.range_slope * (dk / self.near[j]) ** 2) * np.where(
                    partial_k, p.miss.partial_factor, np.where(distant_k, p.miss.distant_factor,
                                                               np.where(nearby_k, p.miss.nearby_factor, 1.0)))
            else:
                mult = np.ones(K)
            u = rng.random((4, K))
            p_miss = np.minimum(1.0, rho * self.miss_scale[j] * mult)
            keep = u[0] >= p_miss
            if p.mode == "realistic":
                for source, target, probability, distant_only in self.confusions:
                    rule = (reported == source) & ~confused & keep
                    if distant_only:
                        rule &= distant_k
                    hit = rule & (u[1] < probability * rho * mult)
                    reported[hit] = target
                    confused |= hit
            xk, yk = self._position_noise(xk, yk, dk, mult, rng)
            g = rng.standard_normal((2, K))
            size_factor = np.maximum(0.2, 1.0 + m * p.position.size_std * g[0])
            yaw_noise = m * p.position.yaw_std * g[1]
            if p.mode == "realistic":
                fp = p.false_positives
                feet = keep & (ck == _ROBOT) & (reported == _ROBOT) & (dk < fp.at_feet_range) \
                    & ~distant_k & ~partial_k & (u[2] < fp.at_feet_probability * m)
                if feet.any():
                    extra.append(self._feet_balls(v[feet], xk[feet], yk[feet], rng))
                    keep &= ~(feet & (u[3] < fp.at_feet_robot_dropped * m))
        seen = np.zeros((V, N), bool)
        truly = keep & ~confused
        seen[v[truly], j[truly]] = True
        context = _ViewContext(f, o, heading, frames, observer_team)
        point_rows = self._point_rows(v[keep], j[keep], reported[keep], xk[keep], yk[keep], context,
                                      size_factor[keep], yaw_noise[keep])
        # The circle keeps the bits of its rim test (every other point report gets them from the report itself).
        point_rows[0]["sighting"] = (distant_k[keep] * _DISTANT | partial_k[keep] * _PARTIAL)
        line_rows, lines_seen = self._line_rows(ox[:, 0], oy[:, 0], ch[:, 0], sh[:, 0], rng)
        rows = [line_rows]
        if p.mode != "none" and p.noise_magnitude > 0.0:
            # Reports no object of their class stands behind: confusions, balls at feet, uniform false positives.
            confused_kept = confused[keep]
            made_up = [(point_rows[0][confused_kept], point_rows[1][confused_kept])] + extra
            made_up.append(self._false_positives(V, rng))
            point_rows = (point_rows[0][~confused_kept], point_rows[1][~confused_kept])
            rows.append(self._made_up_rows(_concatenate(made_up), context, rng))
        rows.append(point_rows)
        return self._assemble(rows, V, seen, lines_seen, visible, rng)

    # ------------------------------------------------------------------------------------------------------------
    def _hidden(self, cx: np.ndarray, cy: np.ndarray, d: np.ndarray, bearing: np.ndarray,
                observer: np.ndarray, in_view: np.ndarray) -> np.ndarray:
        """Objects behind a robot: in its shadow cone (``cone``) or within the occluder radius of the sight line
        through it (``band``, DynEnv's rule, where only robots in the field of view occlude)."""
        k = self.occluder_index
        if len(k) == 0:
            return np.zeros(d.shape, bool)
        occlusion = self.params.occlusion
        dk, bk = d[:, k], bearing[:, k]                                   # (V, K)
        valid = (k[None, :] != observer[:, None]) & (np.abs(bk) < math.pi / 2)   # in front of the observer
        behind = d[:, None, :] > dk[:, :, None] + _EPS
        if occlusion.model == "band":
            valid &= in_view[:, k]
            inv_k = 1.0 / np.maximum(dk, _EPS)
            sx, sy = cx[:, k] * inv_k, cy[:, k] * inv_k                   # unit sight lines to the occluders
            along = sx[:, :, None] * cx[:, None, :] + sy[:, :, None] * cy[:, None, :]      # (V, K, N)
            across = np.abs(sx[:, :, None] * cy[:, None, :] - sy[:, :, None] * cx[:, None, :])
            hide = valid[:, :, None] & behind & (along > 0) & (across < occlusion.occluder_radius)
        else:
            ratio = clamp(occlusion.occluder_radius / np.maximum(dk, _EPS), 0.0, 1.0)
            cos_width = np.sqrt(1.0 - ratio * ratio)
            # cos of the angle between the sight lines to target and occluder, without trigonometry
            inv = 1.0 / np.maximum(d, _EPS)
            ux, uy = cx * inv, cy * inv                                   # unit sight lines (V, N)
            cos_delta = ux[:, None, :] * ux[:, k, None] + uy[:, None, :] * uy[:, k, None]   # (V, K, N)
            hide = valid[:, :, None] & behind & (cos_delta > cos_width[:, :, None])
        hide[:, np.arange(len(k)), k] = False                             # nothing hides itself
        return hide.any(axis=1)

    def _nearby(self, frames: SceneFrames, f: np.ndarray, observer: np.ndarray) -> np.ndarray:
        """Another moving object (not the observer) within ``nearby_distance`` of the object."""
        k = self.dynamic_index
        X, Y = frames.x[f], frames.y[f]
        ddx, ddy = X[:, k, None] - X[:, None, :], Y[:, k, None] - Y[:, None, :]
        close = ddx * ddx + ddy * ddy < self.params.miss.nearby_distance ** 2   # (V, K, N)
        close[:, np.arange(len(k)), k] = False
        close &= (k[None, :, None] != observer[:, None, None])
        return close.any(axis=1)

    def _position_noise(self, x, y, d, mult, rng):
        p, m = self.params.position, self.params.noise_magnitude
        if p.model == "uniform":
            scale = m * p.uniform_scale * (mult if self.params.mode == "realistic" else 4.0)
            u = rng.random((2,) + x.shape) - 0.5
            return x + u[0] * scale, y + u[1] * scale
        return self._polar_point_noise(x, y, rng, d)

    def _point_rows(self, v, j, cls, x, y, context: "_ViewContext", size_factor, yaw_noise):
        """Rows of the detected point objects with their own attributes (confused ones are re-dressed later)."""
        obj = self.objects
        rows = np.zeros(len(v), DETECTION_DTYPE)
        rows["class_id"] = cls
        rows["x"], rows["y"] = x, y
        rows["size_x"] = obj.size_x[j] * size_factor
        rows["size_y"] = obj.size_y[j] * size_factor
        f = context.frame[v]
        is_robot = cls == _ROBOT
        yaw = _wrap(context.frames.yaw[f, j] - context.heading[v] + yaw_noise)
        rows["yaw"] = np.where(is_robot, yaw, np.nan)
        rows["team"] = np.where(is_robot, obj.team[j] * context.observer_team[v], 0)
        rows["fallen"] = is_robot & context.frames.fallen[f, j]
        rows["penalized"] = is_robot & context.frames.penalized[f, j]
        rows["subtype"] = obj.subtype[j]
        rows["true_id"] = obj.object_id[j]
        rows["true_class"] = obj.class_id[j]
        return rows, v

    def _made_up_rows(self, part, context: "_ViewContext", rng: np.random.Generator):
        """Give reports that no object of their class stands behind (false positives, confusions) the attributes
        a real detection of that class has: its class's size with the same size error, and for robots the heading,
        team and state of a randomly chosen other robot of the game (so neither the marginal team mix nor the
        fallen rate differs), for crossings the shape of a randomly chosen real crossing."""
        rows, v = part
        n = len(rows)
        if n == 0:
            return part
        p = self.params
        cls = rows["class_id"].astype(np.intp)
        g = rng.standard_normal((2, n))
        m = p.noise_magnitude
        factor = np.maximum(0.2, 1.0 + m * p.position.size_std * g[0])
        rows["size_x"] = rows["size_y"] = self.class_size[cls] * factor
        rows["yaw"] = np.nan
        rows["team"] = 0
        rows["fallen"] = rows["penalized"] = False
        rows["subtype"] = self._class_subtype[cls]
        robot = np.flatnonzero(cls == _ROBOT)
        if len(robot):
            observer = context.observer[v[robot]]
            others = self.robot_index
            observer_is_robot = self.is_robot[observer]
            choices = len(others) - observer_is_robot.astype(int)
            if len(others) and (choices > 0).all():
                pick = (rng.random(len(robot)) * choices).astype(np.intp)
                pick += observer_is_robot & (pick >= self._robots_before[observer])
                r = others[pick]
                f = context.frame[v[robot]]
                heading = context.heading[v[robot]]
                rows["yaw"][robot] = _wrap(context.frames.yaw[f, r] - heading + m * p.position.yaw_std * g[1, robot])
                rows["team"][robot] = self.objects.team[r] * context.observer_team[v[robot]]
                rows["fallen"][robot] = context.frames.fallen[f, r]
                rows["penalized"][robot] = context.frames.penalized[f, r]
            else:                                        # no other robot to resemble: a plausible stranger
                rows["yaw"][robot] = (rng.random(len(robot)) * 2 - 1) * math.pi
                rows["team"][robot] = np.where(rng.random(len(robot)) < 0.5, -1, 1)
        for c, subtypes in self._varied_subtypes.items():
            at = np.flatnonzero(cls == c)
            if len(at):
                rows["subtype"][at] = subtypes[(rng.random(len(at)) * len(subtypes)).astype(np.intp)]
        return rows, v

    def _feet_balls(self, v: np.ndarray, rx: np.ndarray, ry: np.ndarray, rng: np.random.Generator):
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

    def _false_positives(self, V: int, rng: np.random.Generator):
        """Rule 4, uniform part: ``trials`` chances per frame, anywhere a detection of the drawn class could be —
        uniform in distance up to ``max_distance`` (and the class's range), uniform in bearing across the view
        widened by the class's reach asin(radius / max(distance, 2·radius)), as partially seen real objects are."""
        fp = self.params.false_positives
        counts = rng.binomial(fp.trials, min(1.0, fp.probability * self.params.noise_magnitude), size=V)
        if not counts.any():
            return np.zeros(0, DETECTION_DTYPE), np.zeros(0, np.int64)
        v = np.repeat(np.arange(V), counts)
        u = rng.random((3, len(v)))                                       # every draw at once
        classes = self._fp_classes[(u[0] * len(self._fp_classes)).astype(np.intp)]
        keep = classes != _UNKNOWN
        v, classes, u = v[keep], classes[keep], u[:, keep]
        rows = np.zeros(len(v), DETECTION_DTYPE)
        r = u[1] * np.minimum(fp.max_distance, self.class_max[classes])
        radius = self.class_reach_radius[classes]          # (at most 30°: nothing stands closer than its size)
        reach = np.arcsin(clamp(radius / np.maximum(r, np.maximum(2 * radius, _EPS)), 0.0, 1.0))
        b = (u[2] * 2 - 1) * (self.params.field_of_view / 2 + reach)
        rows["class_id"] = classes
        rows["x"], rows["y"] = r * np.cos(b), r * np.sin(b)
        rows["true_id"] = -1
        return rows, v

    def _assemble(self, parts, V: int, seen, lines_seen, visible, rng: np.random.Generator) -> Perception:
        """All rows of all views, each view's rows nearest first, with the sighting bits and confidences every
        report gets by the same rule whether it is real, confused or false."""
        rows, view = _concatenate(parts)
        distance = np.hypot(rows["x"], rows["y"])
        order = np.lexsort((distance, view))
        # Gathered as raw records: a structured gather copies field by field (ten times slower).
        rows, view, distance = rows.view(_RAW)[order].view(DETECTION_DTYPE), view[order], distance[order]
        offsets = np.zeros(V + 1, np.int64)
        np.cumsum(np.bincount(view, minlength=V), out=offsets[1:])
        self._sighting_bits(rows, view, distance)
        self._confidences(rows, rng)
        return Perception(rows, offsets, seen, lines_seen, visible)

    def _sighting_bits(self, rows: np.ndarray, view: np.ndarray, distance: np.ndarray) -> None:
        """DISTANT, PARTIAL and NEARBY of point reports, from the reports themselves — what a real pipeline can
        compute — so no bit tells a false report from a real one: DISTANT beyond the reported class's near range,
        PARTIAL within the class's reach of the view's edge, NEARBY within ``nearby_distance`` of another reported
        ball or robot of the same frame. Lines keep their clipping bits; the circle its rim test."""
        cls = rows["class_id"].astype(np.intp)
        idx = np.flatnonzero((cls != _FIELD_LINE) & (cls != _CENTER_CIRCLE))
        if not len(idx):
            return
        c, d = cls[idx], distance[idx]
        x, y = rows["x"][idx].astype(float), rows["y"][idx].astype(float)
        reach = np.arcsin(clamp(self.class_reach_radius[c] / np.maximum(d, _EPS), 0.0, 1.0))
        partial = np.abs(np.arctan2(y, x)) > self.params.field_of_view / 2 - reach
        distant = d > self.class_near[c]
        dyn = (c == _BALL) | (c == _ROBOT)
        nearby = np.zeros(len(idx), bool)
        if dyn.any():                  # each report against its own view's ball and robot reports only
            pv = view[idx]
            dv = pv[dyn]
            first = np.searchsorted(dv, pv)                  # views are sorted: a view's dynamic reports are a run
            count = np.searchsorted(dv, pv, side="right") - first
            own = np.flatnonzero(dyn)
            for k in range(int(count.max())):
                at = np.minimum(first + k, len(dv) - 1)
                other = own[at]
                gap2 = (x - x[other]) ** 2 + (y - y[other]) ** 2
                nearby |= (k < count) & (other != np.arange(len(idx))) & (gap2 < self.params.miss.nearby_distance ** 2)
        rows["sighting"][idx] = (distant * _DISTANT | partial * _PARTIAL | nearby * _NEARBY)

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
        cls = rows["class_id"].astype(np.intp)
        correct = (rows["true_id"] != -1) & (rows["true_class"] == rows["class_id"])
        sep = p.confidence_separation
        z = rng.standard_normal(len(rows)) + sep * correct
        logit = self.class_prior_logit[cls] + sep * z - sep * sep / 2
        rows["confidence"] = 1.0 / (1.0 + np.exp(-logit))

    # -- lines and the centre circle ------------------------------------------------------------------------------
    def _line_rows(self, ox, oy, c, s, rng):
        """Field lines clipped to the view wedge and range; DynEnv's endpoint noise and miss rule."""
        lines = self.objects.lines
        V, L = len(ox), len(lines)
        if L == 0:
            return (np.zeros(0, DETECTION_DTYPE), np.zeros(0, np.int64)), np.zeros(V, int)
        dx = lines[None, :, 0::2] - ox[:, None, None]                     # (V, L, 2): both endpoints
        dy = lines[None, :, 1::2] - oy[:, None, None]
        c, s = c[:, None, None], s[:, None, None]
        px, py = c * dx + s * dy, -s * dx + c * dy
        ax, bx, ay, by = px[..., 0], px[..., 1], py[..., 0], py[..., 1]
        half = self.params.field_of_view / 2
        sin_h, cos_h = math.sin(half), math.cos(half)
        edge_y = np.array([-cos_h, cos_h])[:, None, None]                 # the two edges of the view wedge
        lo, hi = _clip_half_plane(sin_h * ax + edge_y * ay, sin_h * bx + edge_y * by, 0.0, 1.0)
        lo, hi = lo.max(axis=0), hi.min(axis=0)
        if math.isfinite(self.line_max):
            lo, hi = _clip_disc(ax, ay, bx, by, self.line_max, lo, hi)
        ex, ey = bx - ax, by - ay
        visible = (hi > lo) & (np.hypot(ex, ey) * (hi - lo) >= MIN_LINE_LENGTH)
        v, k = np.nonzero(visible)
        lo, hi, ax, ay, ex, ey = lo[v, k], hi[v, k], ax[v, k], ay[v, k], ex[v, k], ey[v, k]
        sx, sy, tx, ty = ax + lo * ex, ay + lo * ey, ax + hi * ex, ay + hi * ey
        partial = (lo > _EPS) | (hi < 1 - _EPS)
        d_start, d_end = np.hypot(sx, sy), np.hypot(tx, ty)
        distant = np.maximum(d_start, d_end) > self.line_near
        p = self.params
        keep = np.ones(len(v), bool)
        p_miss = np.zeros(len(v))
        if p.mode != "none" and p.noise_magnitude > 0.0:
            m = p.noise_magnitude
            if p.mode == "realistic":
                mult_s = p.miss.range_offset + p.miss.range_slope * (d_start / self.line_near) ** 2
                mult_e = p.miss.range_offset + p.miss.range_slope * (d_end / self.line_near) ** 2
            else:
                mult_s = mult_e = np.ones(len(v))
            p_miss = np.minimum(1.0, p.rho * self.line_scale * (mult_s + mult_e) / 2)
            keep = rng.random(len(v)) >= p_miss
            if p.position.model == "uniform":
                scale = 2 * m * p.position.uniform_scale
                u = rng.random((4, len(v))) - 0.5
                ms, me = (mult_s, mult_e) if p.mode == "realistic" else (1.0, 1.0)
                sx, sy = sx + u[0] * scale * ms, sy + u[1] * scale * ms
                tx, ty = tx + u[2] * scale * me, ty + u[3] * scale * me
            else:
                nx, ny_ = self._polar_point_noise(np.concatenate((sx, tx)), np.concatenate((sy, ty)), rng,
                                                  np.concatenate((d_start, d_end)))
                n = len(v)
                sx, tx, sy, ty = nx[:n], nx[n:], ny_[:n], ny_[n:]
        v, k = v[keep], k[keep]
        sx, sy, tx, ty = sx[keep], sy[keep], tx[keep], ty[keep]
        # Endpoint order by a rule of the observer's frame alone (nearer end first), so a mirrored or rotated
        # situation gives the mirrored or identical report; an order that follows the field would be a compass.
        # Exact ties (a line square to the gaze, clipped by both edges) go right end first: rotations stay
        # consistent; a perfect tie cannot be mirror-symmetric.
        gap = np.hypot(tx, ty) - np.hypot(sx, sy)
        swap = (gap < -1e-6) | ((np.abs(gap) <= 1e-6) & (ty < sy))
        sx, tx = np.where(swap, tx, sx), np.where(swap, sx, tx)
        sy, ty = np.where(swap, ty, sy), np.where(swap, sy, ty)
        rows = np.zeros(len(v), DETECTION_DTYPE)
        rows["class_id"] = _FIELD_LINE
        rows["line_start_x"], rows["line_start_y"], rows["line_end_x"], rows["line_end_y"] = sx, sy, tx, ty
        ex, ey = tx - sx, ty - sy
        seg2 = np.maximum(ex * ex + ey * ey, _EPS)
        t = clamp(-(sx * ex + sy * ey) / seg2, 0.0, 1.0)                # closest point to the camera
        rows["x"], rows["y"] = sx + t * ex, sy + t * ey
        rows["yaw"] = (np.arctan2(ey, ex) + math.pi / 2) % math.pi - math.pi / 2   # a line has no arrow
        rows["size_x"] = np.sqrt(seg2)
        rows["size_y"] = 0.05
        rows["sighting"] = distant[keep] * _DISTANT | partial[keep] * _PARTIAL
        rows["true_id"] = -2 - k                                          # lines: -2, -3, … (never -1 = FP)
        rows["true_class"] = _FIELD_LINE
        return (rows, v), np.bincount(v, minlength=V)

    def _polar_point_noise(self, x, y, rng, d=None):
        p, m = self.params.position, self.params.noise_magnitude
        g = rng.standard_normal((2,) + np.shape(x))
        if self.params.mode == "random":
            return x + g[0] * m * p.random_std, y + g[1] * m * p.random_std
        d = np.hypot(x, y) if d is None else d
        r = np.maximum(0.0, d + g[0] * m * (p.radial_base + p.radial_per_m2 * d * d))
        b = np.arctan2(y, x) + g[1] * m * p.bearing_std
        return r * np.cos(b), r * np.sin(b)

    def _circle_rim_in_view(self, x0, y0, ox, oy, c, s) -> np.ndarray:
        """(V,) how many rim samples of the circle lie in the view wedge and range."""
        rx = x0[:, None] + self.rim_offsets[None, :, 0] - ox[:, None]
        ry = y0[:, None] + self.rim_offsets[None, :, 1] - oy[:, None]
        px, py = c[:, None] * rx + s[:, None] * ry, -s[:, None] * rx + c[:, None] * ry
        half = self.params.field_of_view / 2
        limit = self.params.classes[ObjectClass.CENTER_CIRCLE].max_range
        inside = (np.abs(np.arctan2(py, px)) <= half) & (px * px + py * py <= limit * limit)
        return inside.sum(axis=1)


def _clip_half_plane(ga, gb, lo, hi):
    """Restrict the segment parameter interval [lo, hi] to where g(t) = ga + t·(gb − ga) ≥ 0."""
    slope = gb - ga
    flat = slope == 0
    t = -ga / np.where(flat, 1.0, slope)
    lo = np.where(slope > 0, np.maximum(lo, t), lo)
    hi = np.where(slope < 0, np.minimum(hi, t), hi)
    outside = flat & (ga < 0)
    return np.where(outside, 1.0, lo), np.where(outside, 0.0, hi)


def _clip_disc(ax, ay, bx, by, radius, lo, hi):
    """Restrict [lo, hi] to the part of the segment within ``radius`` of the camera."""
    ex, ey = bx - ax, by - ay
    a = np.maximum(ex * ex + ey * ey, _EPS)
    b = ax * ex + ay * ey
    disc = b * b - a * (ax * ax + ay * ay - radius * radius)
    root = np.sqrt(np.maximum(disc, 0.0))
    miss = disc < 0
    return np.where(miss, 1.0, np.maximum(lo, (-b - root) / a)), np.where(miss, 0.0, np.minimum(hi, (-b + root) / a))


_RAW = np.dtype((np.void, DETECTION_DTYPE.itemsize))


def _concatenate(parts):
    """(rows, views) parts → one (rows, views). As raw records: numpy's structured concatenate re-promotes every
    field (slow for small parts)."""
    rows = np.concatenate([r.view(_RAW) for r, _ in parts]).view(DETECTION_DTYPE)
    return rows, np.concatenate([v for _, v in parts])


def _wrap(angle: np.ndarray) -> np.ndarray:
    return (angle + math.pi) % (2 * math.pi) - math.pi


@dataclass
class _ViewContext:
    """Per view: its frame, observer, camera heading; the frames; each observer's absolute team."""
    frame: np.ndarray
    observer: np.ndarray
    heading: np.ndarray
    frames: SceneFrames
    observer_team: np.ndarray
