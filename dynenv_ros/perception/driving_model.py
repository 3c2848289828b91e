"""Driving perception: what each car's sensors report in one vision frame — 360° view, occlusion by rotated boxes,
the original's error model with its bugs fixed (docs/perception.md, "Driving").

Scenario-specific where soccer's ``Perceiver`` (perception/model.py) cannot serve without edits: a 360° view (its field
of view must be under π), box occluders with rotated corners (its occluders are discs), three sight lines per
object (hidden / PARTIAL by occlusion instead of by the view's edge), lanes as oriented lane segments and a SELF row.
It reuses the scenario-independent pieces: ``DETECTION_DTYPE`` rows, the Sighting bits, the calibrated-confidence
rule and the same leak rules (every feature of a false or confused report drawn as a real one of its class at that
place would have it). Everything is computed for all cars of a period as one set of arrays.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from dynenv_ros.core.object_classes import ObjectClass, Sighting, Subtype
from dynenv_ros.perception import driving_kernels as kernels
from dynenv_ros.perception.detections import DETECTION_DTYPE
from dynenv_ros.perception.driving_params import POINT_CLASSES, DrivingPerceptionParams

_CAR, _PED, _OBST = int(ObjectClass.CAR), int(ObjectClass.PEDESTRIAN), int(ObjectClass.OBSTACLE)
_LANE, _SELF, _UNKNOWN = int(ObjectClass.LANE), int(ObjectClass.SELF), int(ObjectClass.UNKNOWN)
_DISTANT, _PARTIAL, _NEARBY = int(Sighting.DISTANT), int(Sighting.PARTIAL), int(Sighting.NEARBY)
_SAME, _OPPOSING, _EDGE = int(Subtype.LANE_SAME_DIRECTION), int(Subtype.LANE_OPPOSING), int(Subtype.LANE_EDGE)
LANE_CENTRE, ROAD_EDGE = 0, 1
EGO_COLUMNS = ("speed", "yaw_rate", "goal_x", "goal_y", "length", "width", "crashed", "finished")
EDGE_WIDTH = 0.15            # m: a road edge line's painted width (its report's size_y)
_EPS = 1e-9
_RAW = np.dtype((np.void, DETECTION_DTYPE.itemsize))
_Part = tuple[np.ndarray, np.ndarray]      # report rows and each row's view
# What ``kernels.dress_rows`` takes after the rows and their views (``DrivingPerceiver._dressing``).
_Dressing = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray,
                  bool, bool, float, float, float, float, float]


@dataclass
class DrivingScene:
    """What stays fixed for an episode. Objects are numbered as the world's snapshot ids: cars 0..n−1, pedestrians
    n..n+P−1, obstacles n+P..; each car is also an observer (view v = car v)."""
    car_half_length: np.ndarray          # (n,) m
    car_half_width: np.ndarray           # (n,) m
    car_team: np.ndarray                 # (n,) int8 absolute team
    n_pedestrians: int
    pedestrian_radius: float
    obstacle_xy: np.ndarray              # (O, 2) m, map frame
    obstacle_half: float                 # m, axis-aligned squares
    buildings: np.ndarray                # (B, 5) centre x, y, half x, half y, yaw (rad): rotated boxes
    lanes: np.ndarray                    # (L, 4) x1 y1 x2 y2: lane centres in their direction of travel, road edges
    lane_kind: np.ndarray                # (L,) LANE_CENTRE or ROAD_EDGE
    lane_width: float                    # m: a lane centre's report size_y

    @property
    def n_cars(self) -> int:
        return len(self.car_half_length)


@dataclass
class DrivingState:
    """The world at one vision instant (map frame)."""
    x: np.ndarray; y: np.ndarray; yaw: np.ndarray            # noqa: E702  (n,) cars
    speed: np.ndarray                    # (n,) signed, along the heading, m/s
    yaw_rate: np.ndarray                 # (n,) rad/s
    present: np.ndarray                  # (n,) bool: in the world (a car at its destination has left)
    crashed: np.ndarray                  # (n,) bool
    finished: np.ndarray                 # (n,) bool
    goal_x: np.ndarray; goal_y: np.ndarray                   # noqa: E702  (n,) destinations
    pedestrian_x: np.ndarray; pedestrian_y: np.ndarray       # noqa: E702  (P,)
    pedestrian_alive: np.ndarray         # (P,) bool


@dataclass
class DrivingPerception:
    """All cars' reports of one frame, view after view (view v = car v): per view its SELF row first, then every
    report nearest first. ``of_view(v)`` is a slice (no copy)."""
    detections: np.ndarray               # DETECTION_DTYPE
    offsets: np.ndarray                  # (V + 1,)
    visible: np.ndarray                  # (V, N) bool: in range and not hidden
    seen: np.ndarray                     # (V, N) bool: reported as its own class (before false positives)
    lanes_seen: np.ndarray               # (V,) lanes reported
    ego: np.ndarray                      # (V, 8) float32 EGO_COLUMNS: the SELF rows' values

    def of_view(self, view: int) -> np.ndarray:
        return self.detections[self.offsets[view]:self.offsets[view + 1]]

    def __len__(self) -> int:
        return len(self.offsets) - 1


def _wrap(angle: np.ndarray) -> np.ndarray:
    return (angle + math.pi) % (2 * math.pi) - math.pi


class DrivingPerceiver:
    """Tables for one episode's scene and one parameter set; ``perceive(state, rng)`` once per frame."""

    def __init__(self, scene: DrivingScene, params: DrivingPerceptionParams) -> None:
        self.scene, self.params = scene, params
        n, P, O = scene.n_cars, scene.n_pedestrians, len(scene.obstacle_xy)  # noqa: E741 - counts named as in the docs
        self.n, self.P, self.O = n, P, O
        N = self.N = n + P + O
        self.cls = np.concatenate((np.full(n, _CAR), np.full(P, _PED), np.full(O, _OBST))).astype(np.uint8)
        # Outline per object: box half sizes (hx along its heading, hy across) plus a radius (pedestrians).
        self.hx = np.concatenate((scene.car_half_length, np.zeros(P), np.full(O, scene.obstacle_half)))
        self.hy = np.concatenate((scene.car_half_width, np.zeros(P), np.full(O, scene.obstacle_half)))
        self.rr = np.concatenate((np.zeros(n), np.full(P, scene.pedestrian_radius), np.zeros(O)))
        self.team = scene.car_team.astype(np.int8)
        self.single_team = len(set(self.team.tolist())) <= 1
        t = params.classes
        self.class_near, self.class_max = np.full(256, np.inf), np.full(256, params.view_range)
        self.class_scale, self.class_prior_logit = np.ones(256), np.zeros(256)
        for c, cp in t.items():
            self.class_near[c], self.class_max[c], self.class_scale[c] = cp.near_range, cp.max_range, cp.miss_scale
            self.class_prior_logit[c] = math.log(cp.correct_prior / (1 - cp.correct_prior))
        self.max_range, self.near = self.class_max[self.cls], self.class_near[self.cls]
        # What each occluder kind hides, per class: row 0 buildings (everything), 1 cars, 2 obstacles.
        occ = params.occlusion
        self.hides = np.zeros((3, 256), bool)
        if occ.enabled:
            self.hides[0, list(POINT_CLASSES)] = True
            self.hides[1, [int(c) for c in occ.cars_hide]] = True
            self.hides[2, [int(c) for c in occ.obstacles_hide]] = True
        self._small_hide = self.hides[1] | self.hides[2]
        b = np.asarray(scene.buildings, float).reshape(-1, 5)
        self.B = len(b)
        # Occluders: buildings, then cars, then obstacles; centre, unit axis, half sizes, bounding radius, kind,
        # object index (−1: a building). Cars' rows are refreshed every frame.
        k = self.B + n + O
        self.occ_x, self.occ_y = np.zeros(k), np.zeros(k)
        self.occ_ux, self.occ_uy = np.ones(k), np.zeros(k)
        self.occ_a = np.concatenate((b[:, 2], scene.car_half_length, np.full(O, scene.obstacle_half)))
        self.occ_b = np.concatenate((b[:, 3], scene.car_half_width, np.full(O, scene.obstacle_half)))
        self.occ_r = np.hypot(self.occ_a, self.occ_b)
        self.occ_kind = np.concatenate((np.zeros(self.B, int), np.ones(n, int), np.full(O, 2)))
        self.occ_obj = np.concatenate((np.full(self.B, -1), np.arange(n), n + P + np.arange(O)))
        self.occ_x[:self.B], self.occ_y[:self.B] = b[:, 0], b[:, 1]
        self.occ_ux[:self.B], self.occ_uy[:self.B] = np.cos(b[:, 4]), np.sin(b[:, 4])
        self.occ_x[self.B + n:], self.occ_y[self.B + n:] = scene.obstacle_xy[:, 0], scene.obstacle_xy[:, 1]
        # Object positions: obstacles fixed, the rest written every frame.
        self._x, self._y, self._yaw = np.zeros(N), np.zeros(N), np.zeros(N)
        self._x[n + P:], self._y[n + P:] = scene.obstacle_xy[:, 0], scene.obstacle_xy[:, 1]
        self._present = np.ones(N, bool)
        lanes = np.asarray(scene.lanes, float).reshape(-1, 4)
        self.lanes, self.lane_kind = lanes, np.asarray(scene.lane_kind, int)
        self.lane_heading = np.arctan2(lanes[:, 3] - lanes[:, 1], lanes[:, 2] - lanes[:, 0])
        self.lane_size_y = np.where(self.lane_kind == LANE_CENTRE, scene.lane_width, EDGE_WIDTH)
        self._lane_centre = self.lane_kind == LANE_CENTRE
        miss = params.miss
        self._factor = np.array([miss.partial_factor if bits & _PARTIAL else miss.distant_factor
                                 if bits & _DISTANT else miss.nearby_factor if bits & _NEARBY else 1.0
                                 for bits in range(8)])
        self._confusion_rate, self._confusion_target = np.zeros(512), np.arange(256, dtype=np.uint8)
        for rule in params.confusions:
            rate = rule.probability * params.rho
            self._confusion_rate[int(rule.source) + 256], self._confusion_target[rule.source] = rate, rule.target
            if not rule.distant_only:
                self._confusion_rate[int(rule.source)] = rate
        fp = params.false_positives
        self._fp_classes = np.asarray([int(c) for c in fp.classes], np.uint8)
        self._fp_probability = min(1.0, fp.probability * params.noise_magnitude)
        self._fp_range = np.minimum(fp.max_distance, self.class_max)
        self.noisy = params.mode != "none" and params.noise_magnitude > 0.0
        self._any_hides = bool(self.hides.any())
        self._occluders = (self.occ_x, self.occ_y, self.occ_ux, self.occ_uy, self.occ_a, self.occ_b, self.occ_r,
                           self.occ_kind, self.occ_obj)
        self._nearby2 = params.miss.nearby_distance ** 2
        self._no_self_noise = np.zeros((4, n))
        self._no_draws = np.zeros(0)
        self._no_draws_2d = np.zeros((4, 0))          # a kernel's draw block when nothing is drawn
        # uniform draws per dressed car report: other car, car type, heading; heading error (uniform model); team
        self._dress_draws_per_car = 3 + (params.position.model == "uniform") + (not self.single_team)
        self._position_model = (kernels.UNIFORM_POSITION if params.position.model == "uniform" else
                                kernels.GAUSSIAN_POSITION if params.mode == "random" else kernels.POLAR_POSITION)
        self._lane_len2 = np.maximum((lanes[:, 2] - lanes[:, 0]) ** 2 + (lanes[:, 3] - lanes[:, 1]) ** 2, _EPS)

    # ------------------------------------------------------------------------------------------------------------
    def perceive(self, st: DrivingState, rng: np.random.Generator) -> DrivingPerception:
        p, n, P, N = self.params, self.n, self.P, self.N
        X, Y, YAW, present = self._x, self._y, self._yaw, self._present
        X[:n], Y[:n], YAW[:n] = st.x, st.y, st.yaw
        X[n:n + P], Y[n:n + P] = st.pedestrian_x, st.pedestrian_y
        present[:n], present[n:n + P] = st.present, st.pedestrian_alive
        ox, oy, oyaw = np.asarray(st.x, float), np.asarray(st.y, float), np.asarray(st.yaw, float)
        c, s = np.cos(oyaw), np.sin(oyaw)
        self.occ_x[self.B:self.B + n], self.occ_y[self.B:self.B + n] = ox, oy
        self.occ_ux[self.B:self.B + n], self.occ_uy[self.B:self.B + n] = c, s
        # Every (view, object) pair in range, present and not hidden, in the observer's frame (one compiled pass).
        realistic = p.mode == "realistic"
        visible = np.zeros(n * N, bool)
        miss = p.miss
        at, v, j, xk, yk, dk, bits, mult = kernels.visible_pairs(
            X, Y, np.cos(YAW), np.sin(YAW), present, np.asarray(st.present, bool), self.hx, self.hy, self.rr, self.cls,
            self.max_range, self.near, ox, oy, c, s, *self._occluders, self.hides, self.B, self._any_hides,
            realistic and self.noisy, n, P, self._nearby2, self._factor, miss.range_offset, miss.range_slope,
            miss.range_reference, visible)
        ck = self.cls[j]
        K = len(at)
        made_up = []
        m = p.noise_magnitude
        u = pos = g = self._no_draws_2d
        yu = self._no_draws
        position = self._position_model
        if self.noisy:      # the draws in their fixed order: miss/confusion/near-car, position, size and yaw, yaw
            u = rng.random((4, K))
            pos = rng.random((2, K)) if position == kernels.UNIFORM_POSITION else rng.standard_normal((2, K))
            g = rng.standard_normal((2, K))
            if position == kernels.UNIFORM_POSITION:
                yu = rng.random(K)
        seen = np.zeros(n * N, bool)
        pp, fp = p.position, p.false_positives
        rows, kept, confused, near_car, xk, yk = kernels.pair_reports(
            at, v, j, xk, yk, dk, bits, mult, ck, self.noisy, realistic, bool(p.confusions), position,
            position == kernels.UNIFORM_POSITION, u, pos, g, yu, m, p.rho, self.class_scale, self._confusion_rate,
            self._confusion_target, pp.uniform_scale, pp.random_std, pp.radial_base, pp.radial_per_m2, pp.bearing_std,
            pp.size_std, pp.yaw_std, fp.near_car_range, fp.near_car_probability, _DISTANT, _PARTIAL, seen, self.hx,
            self.hy, self.rr, YAW, oyaw, self.team, n, _CAR)
        if self.noisy and realistic and near_car.any():
            w = near_car.nonzero()[0]
            made_up.append(self._near_car_pedestrians(v[w], xk[w], yk[w], YAW[j[w]] - oyaw[v[w]], self.hx[j[w]],
                                                      self.hy[j[w]], rng))
        v, confused = v[kept], confused[kept]
        parts = [(rows, v)]
        if self.noisy:
            if confused.any():       # re-dressed as a real report of the class it is given as
                w = confused.nonzero()[0]
                rows_c = rows.view(_RAW)[w].view(DETECTION_DTYPE)
                kernels.dress_rows(rows_c, v[w], *self._dressing(rows_c, oyaw, st, rng), _CAR, _PED)
                keep_rows = (~confused).nonzero()[0]
                parts = [(rows.view(_RAW)[keep_rows].view(DETECTION_DTYPE), v[keep_rows]), (rows_c, v[w])]
            made_up.append(self._uniform_false_positives(rng))
            fake = self._place_made_up(made_up, ox, oy, oyaw, c, s, st, rng)
            if fake is not None:
                parts.append(fake)
        lane_rows, lanes_seen = self._lanes(ox, oy, oyaw, c, s, rng)
        parts.append(lane_rows)
        self_rows, ego = self._self_rows(st, ox, oy, c, s, rng)
        parts.append(self_rows)
        return self._assemble(parts, visible.reshape(n, N), seen.reshape(n, N), lanes_seen, ego, rng)

    # -- made-up reports ---------------------------------------------------------------------------------------------
    def _dressing(self, rows: np.ndarray, oyaw: np.ndarray, st: DrivingState, rng: np.random.Generator) -> _Dressing:
        """The draws and scene arrays ``kernels.dress_rows`` needs to dress ``rows``: reports that no object of
        their class stands behind (false positives, confusions) get what a real report of that class has — a car
        the outline, heading (relative, with the heading error) and team of a randomly chosen other car in the
        world (a random car type and heading when there is none); an obstacle or pedestrian its class's size; sizes
        the same size error as real reports. Draws, in this order: (2, K) normal, then (rows, cars) uniform."""
        p = self.params
        g = rng.standard_normal((2, len(rows)))
        ur = rng.random((self._dress_draws_per_car, int(np.count_nonzero(rows["class_id"] == _CAR))))
        return (g, ur, oyaw, np.asarray(st.yaw, float), np.asarray(st.present, bool), self.scene.car_half_length,
                self.scene.car_half_width, self.team, self.single_team,
                self._position_model == kernels.UNIFORM_POSITION,
                p.noise_magnitude, p.position.size_std, p.position.yaw_std, self.scene.pedestrian_radius,
                self.scene.obstacle_half)

    def _uniform_false_positives(self, rng: np.random.Generator) -> _Part:
        """``trials`` chances per view, uniform in distance up to ``max_distance`` (and the class's range) and in
        bearing all round; ``none`` draws nothing."""
        counts = rng.binomial(self.params.false_positives.trials, self._fp_probability, size=self.n)
        u = rng.random((3, int(counts.sum())))
        return kernels.uniform_false_positives(counts, u, self._fp_classes, self._fp_range, _UNKNOWN)

    def _near_car_pedestrians(self, v: np.ndarray, cx: np.ndarray, cy: np.ndarray, yaw: np.ndarray, hx: np.ndarray,
                              hy: np.ndarray, rng: np.random.Generator) -> _Part:
        """Rule 4 of the paper for driving: a pedestrian reported next to a nearby car (the original: 10ρ per car
        seen within 25 m), just outside the car's outline in a random direction."""
        K = len(v)
        u = rng.random((2, K))
        phi = u[0] * 2 * math.pi
        support = hx * np.abs(np.cos(phi - yaw)) + hy * np.abs(np.sin(phi - yaw))
        reach = support + self.scene.pedestrian_radius + u[1] * self.params.false_positives.near_car_spread
        rows = np.zeros(K, DETECTION_DTYPE)
        rows["class_id"] = _PED
        rows["x"], rows["y"] = cx + reach * np.cos(phi), cy + reach * np.sin(phi)
        return rows, v

    def _place_made_up(self, parts: list[_Part], ox: np.ndarray, oy: np.ndarray, oyaw: np.ndarray, c: np.ndarray,
                       s: np.ndarray, st: DrivingState, rng: np.random.Generator) -> _Part | None:
        """Dress the false positives, then keep only those a real object of their class could be seen at (within
        its range, not hidden) with the PARTIAL bit the same occlusion test gives a real one."""
        rows = np.concatenate([r.view(_RAW) for r, _ in parts]).view(DETECTION_DTYPE)
        v = np.concatenate([vv for _, vv in parts]).astype(np.int64)
        if not len(rows):
            return None
        rows["true_id"] = -1
        rows["true_class"] = _UNKNOWN
        return kernels.place_made_up(rows, v, *self._dressing(rows, oyaw, st, rng), _CAR, _PED, ox, oy, c, s,
                                     *self._occluders, self.hides, self.B, self._any_hides, self.class_max, _PARTIAL)

    # -- lanes -------------------------------------------------------------------------------------------------------
    def _lanes(self, ox: np.ndarray, oy: np.ndarray, oyaw: np.ndarray, c: np.ndarray, s: np.ndarray,
               rng: np.random.Generator) -> tuple[_Part, np.ndarray]:
        """Lane centres and road edges within the lane class's range, as segments in the observer's frame."""
        p = self.params
        L, V = len(self.lanes), self.n
        if L == 0:
            return (np.zeros(0, DETECTION_DTYPE), np.zeros(0, np.intp)), np.zeros(V, int)
        R = p.classes[ObjectClass.LANE].max_range
        lv, k, bits, g = kernels.clip_lanes(self.lanes, self._lane_len2, ox, oy, c, s, R, p.lanes.min_length)
        u = n2 = self._no_draws_2d
        lp = p.lanes
        if self.noisy:
            u = rng.random((3, len(lv)))
            if lp.model != "uniform":
                n2 = rng.standard_normal((2, len(lv)))
        # Missed, shifted along the normal and turned about the nearest point when noisy. Endpoint order by a rule
        # of the observer's frame alone: nearer end first; equally far ends (both clipped at the range) rear end
        # first, which a mirror image keeps; then the right end first. Never the map's direction of the line.
        rows, views, lanes_seen = kernels.lane_reports(
            lv, k, bits, g, self.noisy, p.mode == "realistic", lp.model == "uniform", u, n2, p.noise_magnitude,
            p.rho * self.class_scale[_LANE], p.miss.range_offset, p.miss.range_slope, p.miss.range_reference,
            lp.lateral_uniform, lp.angle_uniform, lp.lateral_base, lp.lateral_per_m2, lp.angle_std,
            self.lane_heading, oyaw, self._lane_centre, self.lane_size_y, V, _LANE, _SAME, _OPPOSING,
            _EDGE)
        return (rows, views), lanes_seen

    # -- the observer itself -------------------------------------------------------------------------------------------
    def _self_rows(self, st: DrivingState, ox: np.ndarray, oy: np.ndarray, c: np.ndarray, s: np.ndarray,
                   rng: np.random.Generator) -> tuple[_Part, np.ndarray]:
        """One SELF row per car: what it knows of itself — its destination in its own frame (navigation), speed and
        yaw rate (odometry) as ``line_start`` (x: speed m/s, y: yaw rate rad/s), its outline, crashed (``fallen``)
        and finished (``penalized``). Never a map-frame pose."""
        V = self.n
        speed, yaw_rate = np.asarray(st.speed, float), np.asarray(st.yaw_rate, float)
        sp, m = self.params.self_state, self.params.noise_magnitude
        g = rng.standard_normal((4, V)) if self.noisy else self._no_self_noise
        rows, ego = np.zeros(V, DETECTION_DTYPE), np.empty((V, len(EGO_COLUMNS)), np.float32)
        kernels.self_rows(rows, ego, np.asarray(st.goal_x, float), np.asarray(st.goal_y, float), ox, oy, c, s, speed,
                          yaw_rate, g, self.noisy, m, sp.speed_std, sp.yaw_rate_std, sp.goal_std,
                          self.scene.car_half_length, self.scene.car_half_width, np.asarray(st.crashed, bool),
                          np.asarray(st.finished, bool), _SELF)
        return (rows, np.arange(V)), ego

    # -- assembly ----------------------------------------------------------------------------------------------------
    def _assemble(self, parts: list[_Part], visible: np.ndarray, seen: np.ndarray, lanes_seen: np.ndarray,
                  ego: np.ndarray, rng: np.random.Generator) -> DrivingPerception:
        rows = np.concatenate([r.view(_RAW) for r, _ in parts]).view(DETECTION_DTYPE)
        view = np.concatenate([v for _, v in parts]).astype(np.int64)
        distance = np.hypot(rows["x"], rows["y"]).astype(np.float32)
        # Sorted, DISTANT and NEARBY from the report itself (one rule for real and made-up reports alike), and the
        # confidence: the calibrated detector score of perception/model.py (docs/perception.md); SELF rows 1.
        p = self.params
        calibrated = p.confidence != "none"
        z = rng.standard_normal(len(rows)) if calibrated else self._no_draws
        rows, offsets = kernels.finish_rows(rows, view, distance, self.n, _SELF, self.class_near,
                                            p.miss.nearby_distance ** 2, _CAR, _PED, _OBST, _DISTANT, _PARTIAL,
                                            _NEARBY, z, float(p.confidence_separation), self.class_prior_logit,
                                            calibrated)
        return DrivingPerception(rows, offsets, visible, seen, lanes_seen, ego)


__all__ = ["DrivingScene", "DrivingState", "DrivingPerception", "DrivingPerceiver", "EGO_COLUMNS", "LANE_CENTRE",
           "ROAD_EDGE"]
