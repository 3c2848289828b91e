"""Compiled parts of the soccer perception (``model.py``): line clipping and the line reports, the circle's rim
test, occlusion by robots, and the sighting bits of the assembled reports, as numba kernels (``@njit(cache=True)``).

As in ``driving_kernels.py``, each kernel does, entry by entry, exactly the floating-point operations the numpy
expressions it replaces did, in the same order, so the outputs are bit-identical. Numpy's float64 hypot, arctan2,
arcsin, exp, cos and sin are not always libm's to the last bit on this path (numpy's SIMD loops), so those stay in
numpy, called by ``model.py`` between the kernels; sqrt and the arithmetic are IEEE-exact. No kernel draws random
numbers: every draw stays in the caller's seeded ``numpy.random.Generator``, same draws in the same order.

Imported only where a ``Perceiver`` is built (numba costs ≈ 1 s and ≈ 80 MB of memory to import), never on the
physics-and-rules path. The first call of each kernel compiles it (or loads it from ``__pycache__``), which
``warm_up()`` does once per process.
"""
from __future__ import annotations

import math
from typing import Any, TypeVar

import numba
import numpy as np

from dynenv_ros.perception.detections import DETECTION_DTYPE as _DETECTION
from dynenv_ros.perception.row_kernels import clamped_features, sort_by_view

_EPS = 1e-9
_R = TypeVar("_R", float, np.floating[Any])     # a Python or a numpy float (for mypy; numba types each call)


@numba.njit(cache=True, inline="always")
def _maximum(a: _R, b: _R) -> _R:
    """``np.maximum`` to the bit: NaN if either is, and the second operand of equal ones (−0.0, 0.0 → 0.0)."""
    return a if (a > b or a != a) else b


@numba.njit(cache=True, inline="always")
def _minimum(a: _R, b: _R) -> _R:
    """``np.minimum`` to the bit (see ``_maximum``)."""
    return a if (a < b or a != a) else b


@numba.njit(cache=True)
def line_clip(line_x: np.ndarray, line_y: np.ndarray, lv: np.ndarray, ox: np.ndarray, oy: np.ndarray, c: np.ndarray,
              s: np.ndarray, half_sin: float, half_cos: float, line_max: float, finite_range: bool) -> np.ndarray:
    """Every (view, line) of ``_Layout``'s endpoint tables (first endpoints, then second ones) in the camera frame
    and clipped to the view wedge (and range): rows ax, ay, ex, ey (first end and direction) and lo, hi (the
    clipped part's bounds along it)."""
    VL = len(lv) // 2
    out = np.empty((6, VL))
    for i in range(VL):
        v0, v1 = lv[i], lv[VL + i]
        dx0, dy0 = line_x[i] - ox[v0], line_y[i] - oy[v0]
        dx1, dy1 = line_x[VL + i] - ox[v1], line_y[VL + i] - oy[v1]
        c0, s0, c1, s1 = c[v0], s[v0], c[v1], s[v1]
        px0, py0 = c0 * dx0 + s0 * dy0, c0 * dy0 - s0 * dx0
        px1, py1 = c1 * dx1 + s1 * dy1, c1 * dy1 - s1 * dx1
        ax, ay = px0, py0
        ex, ey = px1 - ax, py1 - ay
        sp0, cq0 = half_sin * px0, half_cos * py0
        sp1, cq1 = half_sin * px1, half_cos * py1
        lo = 0.0
        hi = 1.0
        enter0 = enter1 = leave0 = leave1 = 0.0
        for edge in range(2):
            if edge == 0:
                ga, gb = sp0 - cq0, sp1 - cq1
            else:
                ga, gb = sp0 + cq0, sp1 + cq1
            slope = gb - ga
            t = -ga / (1.0 if slope == 0 else slope)
            enter = t if slope > 0 else (2.0 if ga < 0 else 0.0)
            leave = t if slope < 0 else 1.0
            if edge == 0:
                enter0, leave0 = enter, leave
            else:
                enter1, leave1 = enter, leave
        lo = _maximum(_maximum(enter0, enter1), 0.0)
        hi = _minimum(_minimum(leave0, leave1), 1.0)
        if finite_range:
            len2 = _maximum(ex * ex + ey * ey, _EPS)
            b = ax * ex + ay * ey
            disc = b * b - len2 * (ax * ax + ay * ay - line_max * line_max)
            root = math.sqrt(_maximum(disc, 0.0))
            lo = _maximum(lo, (-b - root) / len2)
            hi = _minimum(hi, (-b + root) / len2)
        out[0, i], out[1, i], out[2, i], out[3, i], out[4, i], out[5, i] = ax, ay, ex, ey, lo, hi
    return out


@numba.njit(cache=True)
def line_visible(clip: np.ndarray, length: np.ndarray, lv: np.ndarray, L: int, min_length: float,
                 partial: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The (view, line) pairs with at least ``min_length`` in view (``length``: numpy's hypot of the direction):
    their view, line, clipped ends as (coordinate, start/end, pair) and PARTIAL if clipped."""
    VL = clip.shape[1]
    K = 0
    for i in range(VL):
        lo, hi = clip[4, i], clip[5, i]
        if hi > lo and length[i] * (hi - lo) >= min_length:
            K += 1
    v = np.empty(K, np.int64)
    k = np.empty(K, np.int64)
    ends = np.empty((2, 2, K))
    bits = np.empty(K, np.int64)
    r = 0
    for i in range(VL):
        lo, hi = clip[4, i], clip[5, i]
        if not (hi > lo and length[i] * (hi - lo) >= min_length):
            continue
        vv = lv[i]
        v[r], k[r] = vv, i - vv * L
        ax, ay, ex, ey = clip[0, i], clip[1, i], clip[2, i], clip[3, i]
        ends[0, 0, r], ends[1, 0, r] = ax + lo * ex, ay + lo * ey
        ends[0, 1, r], ends[1, 1, r] = ax + hi * ex, ay + hi * ey
        bits[r] = partial if (lo > _EPS or hi < 1 - _EPS) else 0
        r += 1
    return v, k, ends, bits


@numba.njit(cache=True)
def line_miss(dist: np.ndarray, bits: np.ndarray, near: float, realistic: bool, range_offset: float, range_slope: float,
              rho_scale: float) -> tuple[np.ndarray, np.ndarray]:
    """DISTANT added to ``bits`` (the farther end beyond ``near``); the miss multipliers (2, K) of both ends and the
    miss probability of each line."""
    K = len(bits)
    mult = np.ones((2, K))
    p_miss = np.empty(K)
    for i in range(K):
        if max(dist[0, i], dist[1, i]) > near:
            bits[i] += 1
        if realistic:
            for e in range(2):
                q = dist[e, i] / near
                mult[e, i] = range_offset + range_slope * (q * q)
        p_miss[i] = _minimum(1.0, rho_scale * (mult[0, i] + mult[1, i]) / 2)
    return mult, p_miss


@numba.njit(cache=True)
def line_rows(ends: np.ndarray, reach: np.ndarray, kept: np.ndarray, v: np.ndarray, k: np.ndarray, bits: np.ndarray,
              n_views: int, line_class: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The reports of lines ``kept`` (indices into ``ends`` (coordinate, start/end, K) and ``reach``, the ends'
    distances): nearer end first (ties within 1e-6: the right end first), the point nearest the camera, length;
    all fields but the yaw, whose direction (ex, ey) it returns; each report's view and the count per view."""
    M = len(kept)
    rows = np.zeros(M, _DETECTION)
    exo, eyo = np.empty(M), np.empty(M)
    views = np.empty(M, np.int64)
    seen = np.zeros(n_views, np.int64)
    for r in range(M):
        i = kept[r]
        x0, y0, x1, y1 = ends[0, 0, i], ends[1, 0, i], ends[0, 1, i], ends[1, 1, i]
        gap = reach[1, i] - reach[0, i]
        if gap < -1e-6 or (abs(gap) <= 1e-6 and y1 < y0):
            x0, y0, x1, y1 = x1, y1, x0, y0
        ex, ey = x1 - x0, y1 - y0
        seg2 = _maximum(ex * ex + ey * ey, _EPS)
        t = _minimum(_maximum(-(x0 * ex + y0 * ey) / seg2, 0.0), 1.0)
        w = rows[r]
        w.class_id = line_class
        w.line_start_x, w.line_start_y, w.line_end_x, w.line_end_y = x0, y0, x1, y1
        w.x, w.y = x0 + t * ex, y0 + t * ey
        w.size_x = math.sqrt(seg2)
        w.size_y = 0.05
        w.sighting = bits[i]
        w.true_id = -2 - k[i]
        w.true_class = line_class
        exo[r], eyo[r] = ex, ey
        views[r] = v[i]
        seen[v[i]] += 1
    return rows, views, seen, exo, eyo


@numba.njit(cache=True)
def hidden(at: np.ndarray, j: np.ndarray, pair_view: np.ndarray, cx: np.ndarray, cy: np.ndarray, d: np.ndarray,
           bearing: np.ndarray, in_view: np.ndarray, occluder_pair: np.ndarray, not_observer: np.ndarray,
           occluder_object: np.ndarray, band: bool, radius: float) -> np.ndarray:
    """For the candidate pairs ``at`` (objects ``j``): hidden behind a robot in front of the observer (``band``:
    DynEnv's rule, one in the view too) — farther than it and in its shadow cone, or (``band``) within ``radius``
    of the sight line through it. Nothing hides itself."""
    C, K = len(at), occluder_pair.shape[0]
    out = np.zeros(C, np.bool_)
    half_pi = math.pi / 2
    for q in range(C):
        a = at[q]
        vv = pair_view[a]
        da = d[a]
        inv = 1.0 / _maximum(da, _EPS)
        ux, uy = cx[a] * inv, cy[a] * inv
        for k in range(K):
            o = occluder_pair[k, vv]
            if not (not_observer[k, vv] and abs(bearing[o]) < half_pi) or occluder_object[k] == j[q]:
                continue
            if band and not in_view[o]:
                continue
            dk = d[o]
            if not da > dk + _EPS:
                continue
            if band:
                inv_k = 1.0 / _maximum(dk, _EPS)
                sx, sy = cx[o] * inv_k, cy[o] * inv_k
                x, y = cx[a], cy[a]
                if sx * x + sy * y > 0 and abs(sx * y - sy * x) < radius:
                    out[q] = True
                    break
            else:
                ratio = _minimum(_maximum(radius / _maximum(dk, _EPS), 0.0), 1.0)
                cos_width = math.sqrt(1.0 - ratio * ratio)
                inv_o = 1.0 / _maximum(dk, _EPS)
                if ux * (cx[o] * inv_o) + uy * (cy[o] * inv_o) > cos_width:
                    out[q] = True
                    break
    return out


@numba.njit(cache=True)
def rim_points(fx: np.ndarray, fy: np.ndarray, rim_circle: np.ndarray, rim_observer: np.ndarray, rim_x: np.ndarray,
               rim_y: np.ndarray, rim_view: np.ndarray, c: np.ndarray, s: np.ndarray,
               limit: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The circle's rim samples of every view in the camera frame (px, py) and whether each is within range."""
    n = len(rim_view)
    px, py = np.empty(n), np.empty(n)
    in_range = np.empty(n, np.bool_)
    for i in range(n):
        rx = fx[rim_circle[i]] + rim_x[i] - fx[rim_observer[i]]
        ry = fy[rim_circle[i]] + rim_y[i] - fy[rim_observer[i]]
        cr, sr = c[rim_view[i]], s[rim_view[i]]
        x, y = cr * rx + sr * ry, cr * ry - sr * rx
        px[i], py[i] = x, y
        in_range[i] = x * x + y * y <= limit * limit
    return px, py, in_range


@numba.njit(cache=True)
def rim_count(angle: np.ndarray, in_range: np.ndarray, half: float, samples: int) -> np.ndarray:
    """Per view: how many rim samples are in range with |angle| within ``half``."""
    V = len(angle) // samples
    out = np.zeros(V, np.int64)
    for v in range(V):
        n = 0
        for i in range(v * samples, (v + 1) * samples):
            if abs(angle[i]) <= half and in_range[i]:
                n += 1
        out[v] = n
    return out


@numba.njit(cache=True)
def observation_rewards(seen: np.ndarray, lines_seen: np.ndarray, n: int, landmark_index: np.ndarray,
                        robot_cap: int, landmark_cap: float, ball_cap: int, robot_weight: float,
                        landmark_weight: float, ball_weight: float) -> np.ndarray:
    """``SoccerVision.observation_rewards`` in one pass: views v = frame·n + observer of ``seen`` (V, N) and
    ``lines_seen`` (V,); the counts are integers (exact in any order), the float terms those of the numpy code, in
    its order."""
    V, N = seen.shape
    frames = V // n
    counts = np.zeros((n, N), np.int64)
    lines = np.zeros(n, np.int64)
    for v in range(V):
        i = v % n
        lines[i] += lines_seen[v]
        for j in range(N):
            if seen[v, j]:
                counts[i, j] += 1
    out = np.empty(n)
    for i in range(n):
        robots = 0
        for r in range(n):
            if r != i:
                robots += min(robot_cap, counts[i, r])
        landmarks = lines[i]
        for j in landmark_index:
            landmarks += counts[i, j]
        landmark_term = _minimum(landmark_cap, landmarks / frames)
        ball = min(ball_cap, counts[i, n])
        out[i] = robot_weight * robots + landmark_weight * landmark_term + ball_weight * ball
    return out


@numba.njit(cache=True)
def camera_offsets(fx: np.ndarray, fy: np.ndarray, pair_source: np.ndarray, observer_of_pair: np.ndarray,
                   pair_view: np.ndarray, ch: np.ndarray, sh: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Every (view, object) pair's offset from the observer in the camera frame (x along the gaze, y left):
    ``c·dx + s·dy`` and ``c·dy − s·dx`` of the world offsets, with the view's heading cosine and sine."""
    P = len(pair_source)
    cx = np.empty(P)
    cy = np.empty(P)
    for i in range(P):
        dx = fx[pair_source[i]] - fx[observer_of_pair[i]]
        dy = fy[pair_source[i]] - fy[observer_of_pair[i]]
        c, s = ch[pair_view[i]], sh[pair_view[i]]
        cx[i] = c * dx + s * dy
        cy[i] = c * dy - s * dx
    return cx, cy


@numba.njit(cache=True)
def reach_ratio(radius: np.ndarray, d: np.ndarray) -> np.ndarray:
    """``min(radius / max(d, ε), 1)`` per pair: the sine of the angle an object's reach adds to the view."""
    out = np.empty(len(d))
    for i in range(len(d)):
        out[i] = _minimum(radius[i] / _maximum(d[i], _EPS), 1.0)
    return out


@numba.njit(cache=True)
def in_view_partial(bearing: np.ndarray, reach: np.ndarray, d: np.ndarray, max_range: np.ndarray, half: float,
                    own_pair: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per pair: in the view (within the half angle widened by the reach, and in range; never one's own pair),
    and partial (within the reach of the view's edge)."""
    P = len(d)
    in_view = np.empty(P, np.bool_)
    partial = np.empty(P, np.bool_)
    for i in range(P):
        off_axis = abs(bearing[i])
        in_view[i] = (off_axis <= half + reach[i]) and (d[i] <= max_range[i])
        partial[i] = off_axis > half - reach[i]
    for v in range(len(own_pair)):
        in_view[own_pair[v]] = False
    return in_view, partial


@numba.njit(cache=True)
def visible_pairs(at: np.ndarray, j: np.ndarray, hidden: np.ndarray, circle: int, pair_view: np.ndarray,
                  d: np.ndarray, partial: np.ndarray, cx: np.ndarray, cy: np.ndarray, class_id: np.ndarray,
                  near: np.ndarray, pairs: int, distant_bit: int, partial_bit: int
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray,
                             np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The candidates ``at`` (objects ``j``) not ``hidden`` (the circle never is; ``circle`` −1: none), and per
    visible pair its view, distance, class, the class's near range, DISTANT, the geometric sighting bits, camera
    position; and the (V·N,) visible flags."""
    K = 0
    for q in range(len(at)):
        if not hidden[q] or j[q] == circle:
            K += 1
    out_at = np.empty(K, np.int64)
    out_j = np.empty(K, np.int64)
    v = np.empty(K, np.int64)
    dk = np.empty(K)
    ck = np.empty(K, np.uint8)
    near_k = np.empty(K)
    distant = np.empty(K, np.bool_)
    bits = np.empty(K, np.int64)
    xk = np.empty(K)
    yk = np.empty(K)
    visible = np.zeros(pairs, np.bool_)
    r = 0
    for q in range(len(at)):
        if hidden[q] and j[q] != circle:
            continue
        a, jj = at[q], j[q]
        out_at[r], out_j[r], v[r] = a, jj, pair_view[a]
        dk[r], ck[r], near_k[r] = d[a], class_id[jj], near[jj]
        distant[r] = d[a] > near[jj]
        bits[r] = (partial_bit if partial[a] else 0) + (distant_bit if distant[r] else 0)
        xk[r], yk[r] = cx[a], cy[a]
        visible[a] = True
        r += 1
    return out_at, out_j, v, dk, ck, near_k, distant, bits, xk, yk, visible


@numba.njit(cache=True)
def realistic_misses(fx: np.ndarray, fy: np.ndarray, close_first: np.ndarray, close_second: np.ndarray,
                     close_self: np.ndarray, frames: int, dynamic: int, objects: int, pair_source: np.ndarray,
                     observer_closeness: np.ndarray, at: np.ndarray, j: np.ndarray, bits: np.ndarray,
                     dk: np.ndarray, near: np.ndarray, ck: np.ndarray, distant: np.ndarray, circle: int,
                     sighting_factor: np.ndarray, nearby_bit: int, range_offset: float, range_slope: float,
                     nearby_distance2: float, miss_scale: np.ndarray, rho: float, u: np.ndarray, confusions: bool,
                     confusion_rate: np.ndarray, confusion_target: np.ndarray
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The realistic mode's rules 1–3 for the visible pairs, as ``model.py``'s numpy code did them: NEARBY (another
    moving object, not the observer, within the nearby distance: ``Perceiver._nearby``), the miss multiplier, the
    miss draw ``u[0]`` and (``confusions``: the rules as one table, ``Perceiver._confuse``) the confusion draw
    ``u[1]``. Returns (multiplier, kept, reported class, confused)."""
    F, D, N = frames, dynamic, objects
    close = np.zeros(F * (D + 1) * N, np.bool_)              # (frame, dynamic + a row of none, object)
    for f in range(F):
        for k in range(D):
            for jj in range(N):
                e = (f * D + k) * N + jj
                ddx = fx[close_first[e]] - fx[close_second[e]]
                ddy = fy[close_first[e]] - fy[close_second[e]]
                close[(f * (D + 1) + k) * N + jj] = ddx * ddx + ddy * ddy < nearby_distance2
    for e in range(len(close_self)):
        close[close_self[e]] = False                         # an object is not its own neighbour
    count = np.zeros(F * N, np.int64)
    for f in range(F):
        for k in range(D + 1):
            for jj in range(N):
                if close[(f * (D + 1) + k) * N + jj]:
                    count[f * N + jj] += 1
    K = len(at)
    mult = np.empty(K)
    keep = np.empty(K, np.bool_)
    reported = ck.copy()
    confused = np.zeros(K, np.bool_)
    for q in range(K):
        a = at[q]
        nearby = count[pair_source[a]] > close[observer_closeness[a]] and j[q] != circle
        factor = sighting_factor[bits[q] + (nearby_bit if nearby else 0)]
        ratio = dk[q] / near[q]
        mult[q] = (range_offset + range_slope * (ratio * ratio)) * factor
        p_miss = _minimum(1.0, rho * miss_scale[j[q]] * mult[q])
        keep[q] = u[0, q] >= p_miss
        if confusions:
            c = ck[q]
            hit = keep[q] and u[1, q] < confusion_rate[c + (256 if distant[q] else 0)] * mult[q]
            confused[q] = hit
            if hit:
                reported[q] = confusion_target[c]
    return mult, keep, reported, confused


@numba.njit(cache=True)
def polar_radius_bearing(d: np.ndarray, g: np.ndarray, bearing: np.ndarray, m: float, radial_base: float,
                         radial_per_m2: float, bearing_std: float) -> tuple[np.ndarray, np.ndarray]:
    """The polar error model's noisy radius ``max(0, d + g₀·m·(base + per_m²·d·d))`` and bearing
    ``bearing + g₁·m·std`` (``Perceiver._polar_point_noise``)."""
    n = len(d)
    r = np.empty(n)
    b = np.empty(n)
    for i in range(n):
        r[i] = _maximum(0.0, d[i] + g[0, i] * m * (radial_base + radial_per_m2 * d[i] * d[i]))
        b[i] = bearing[i] + g[1, i] * m * bearing_std
    return r, b


@numba.njit(cache=True)
def polar_points(r: np.ndarray, cos_b: np.ndarray, sin_b: np.ndarray) -> np.ndarray:
    """(2, n): ``r·cos b`` and ``r·sin b``."""
    out = np.empty((2, len(r)))
    for i in range(len(r)):
        out[0, i] = r[i] * cos_b[i]
        out[1, i] = r[i] * sin_b[i]
    return out


@numba.njit(cache=True)
def feet_and_errors(ck: np.ndarray, reported: np.ndarray, keep: np.ndarray, dk: np.ndarray, bits: np.ndarray,
                    u: np.ndarray, g: np.ndarray, m: float, size_std: float, yaw_std: float, realistic: bool,
                    feet_range: float, feet_probability: float, feet_dropped: float, robot: int
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Size factor ``max(0.2, 1 + m·std·g₀)``, yaw error ``m·std·g₁``; realistic mode: the robots that get a ball
    at their feet (rule 4, draw ``u[2]``), and ``keep`` without those whose robot report that ball replaces
    (draw ``u[3]``). Returns (size factor, yaw error, feet pairs, kept)."""
    K = len(dk)
    size_factor = np.empty(K)
    yaw_noise = np.empty(K)
    feet = np.zeros(K, np.bool_)
    n_feet = 0
    for q in range(K):
        size_factor[q] = _maximum(0.2, 1.0 + m * size_std * g[0, q])
        yaw_noise[q] = m * yaw_std * g[1, q]
        if realistic:
            feet[q] = (ck[q] == robot and reported[q] == robot and keep[q] and dk[q] < feet_range and bits[q] == 0
                       and u[2, q] < feet_probability * m)
            if feet[q]:
                n_feet += 1
    at_feet = np.empty(n_feet, np.int64)
    kept = keep.copy()
    r = 0
    for q in range(K):
        if feet[q]:
            at_feet[r] = q
            r += 1
            if u[3, q] < feet_dropped * m:
                kept[q] = False
    return size_factor, yaw_noise, at_feet, kept


@numba.njit(cache=True)
def point_rows(keep: np.ndarray, confused: np.ndarray, at: np.ndarray, v: np.ndarray, j: np.ndarray,
               pair_source: np.ndarray, reported: np.ndarray, x: np.ndarray, y: np.ndarray, size_factor: np.ndarray,
               yaw_noise: np.ndarray, bits: np.ndarray, yaw: np.ndarray, heading: np.ndarray,
               observer_team: np.ndarray, fallen: np.ndarray, penalized: np.ndarray, size_x: np.ndarray,
               size_y: np.ndarray, team: np.ndarray, subtype: np.ndarray, object_id: np.ndarray,
               class_id: np.ndarray, robot: int, pairs: int
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The kept visible pairs' detection rows with their own object's attributes and
    the geometric sighting bits, split into the unconfused ones and the confused ones (re-dressed later, as made-up
    reports), each with its rows' views; and ``seen`` (V·N,): pairs truly detected as their own class."""
    K = len(at)
    n_kept = 0
    n_confused = 0
    seen = np.zeros(pairs, np.bool_)
    for q in range(K):
        if keep[q]:
            n_kept += 1
            if confused[q]:
                n_confused += 1
            else:
                seen[at[q]] = True
    rows = np.zeros(n_kept - n_confused, _DETECTION)
    views = np.empty(n_kept - n_confused, np.int64)
    confused_rows = np.zeros(n_confused, _DETECTION)
    confused_views = np.empty(n_confused, np.int64)
    r = 0
    c = 0
    for q in range(K):
        if not keep[q]:
            continue
        if confused[q]:
            row = confused_rows[c:c + 1]
            confused_views[c] = v[q]
            c += 1
        else:
            row = rows[r:r + 1]
            views[r] = v[q]
            r += 1
        jj, src = j[q], pair_source[at[q]]
        is_robot = reported[q] == robot
        row[0].class_id = reported[q]
        row[0].x = x[q]
        row[0].y = y[q]
        row[0].size_x = size_x[jj] * size_factor[q]
        row[0].size_y = size_y[jj] * size_factor[q]
        if is_robot:
            row[0].yaw = (yaw[src] - heading[v[q]] + yaw_noise[q] + math.pi) % (2 * math.pi) - math.pi
            row[0].team = team[jj] * observer_team[v[q]]
            row[0].fallen = fallen[src]
            row[0].penalized = penalized[src]
        else:
            row[0].yaw = np.nan
            row[0].team = 0
            row[0].fallen = False
            row[0].penalized = False
        row[0].subtype = subtype[jj]
        row[0].true_id = object_id[jj]
        row[0].true_class = class_id[jj]
        row[0].sighting = bits[q]
    return rows, views, confused_rows, confused_views, seen


@numba.njit(cache=True)
def false_positive_draws(counts: np.ndarray, u: np.ndarray, fp_classes: np.ndarray, drop_unknown: bool,
                         unknown: int, fp_range: np.ndarray, reach_radius: np.ndarray, fp_floor: np.ndarray
                         ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Rule 4's uniform false positives from the draws ``u`` (3, M) of the M = Σ ``counts`` chances (view v has
    ``counts[v]``): each chance's class (``drop_unknown``: a drawn ``unknown`` is no report), and per report its
    view, class, distance ``u₁·range``, the sine ``clamp(radius / max(r, floor), 0, 1)`` of its reach and ``u₂``."""
    M = u.shape[1]
    n_classes = len(fp_classes)
    classes_all = np.empty(M, np.uint8)
    n = 0
    for i in range(M):
        classes_all[i] = fp_classes[np.intp(u[0, i] * n_classes)]
        if not (drop_unknown and classes_all[i] == unknown):
            n += 1
    views = np.empty(n, np.int64)
    classes = np.empty(n, np.uint8)
    r = np.empty(n)
    ratio = np.empty(n)
    u2 = np.empty(n)
    i = 0
    q = 0
    for view in range(len(counts)):
        for _ in range(counts[view]):
            c = classes_all[i]
            if not (drop_unknown and c == unknown):
                views[q], classes[q] = view, c
                r[q] = u[1, i] * fp_range[c]
                ratio[q] = _minimum(_maximum(reach_radius[c] / _maximum(r[q], fp_floor[c]), 0.0), 1.0)
                u2[q] = u[2, i]
                q += 1
            i += 1
    return views, classes, r, ratio, u2


@numba.njit(cache=True)
def false_positive_bearings(u2: np.ndarray, reach: np.ndarray, half: float) -> np.ndarray:
    """``(u₂·2 − 1)·(half + reach)``: uniform across the view widened by the class's reach."""
    out = np.empty(len(u2))
    for i in range(len(u2)):
        out[i] = (u2[i] * 2 - 1) * (half + reach[i])
    return out


@numba.njit(cache=True)
def false_positive_rows(classes: np.ndarray, r: np.ndarray, cos_b: np.ndarray, sin_b: np.ndarray) -> np.ndarray:
    """The false positives' rows: class, position ``r·(cos b, sin b)``, no source (``true_id`` −1)."""
    rows = np.zeros(len(classes), _DETECTION)
    for i in range(len(classes)):
        rows[i].class_id = classes[i]
        rows[i].x = r[i] * cos_b[i]
        rows[i].y = r[i] * sin_b[i]
        rows[i].true_id = -1
    return rows


@numba.njit(cache=True)
def dress_made_up(rows: np.ndarray, views: np.ndarray, g: np.ndarray, m: float, size_std: float, yaw_std: float,
                  class_size: np.ndarray, class_subtype: np.ndarray, robot: int, robot_rows: np.ndarray,
                  pick_draws: np.ndarray, view_observer: np.ndarray, view_frame: np.ndarray, heading: np.ndarray,
                  observer_team: np.ndarray, is_robot: np.ndarray, robots_before: np.ndarray, others: np.ndarray,
                  yaw: np.ndarray, fallen: np.ndarray, penalized: np.ndarray, team: np.ndarray, objects: int) -> None:
    """``Perceiver._made_up_rows`` for a game with another robot for every observer: each report its class's
    size with a size error, no yaw, team or flags, its class's subtype; each robot report (``robot_rows``) the
    heading, team and state of another robot, drawn by ``pick_draws``."""
    for i in range(len(rows)):
        factor = _maximum(0.2, 1.0 + m * size_std * g[0, i])
        size = class_size[rows[i].class_id] * factor
        rows[i].size_x = size
        rows[i].size_y = size
        rows[i].yaw = np.nan
        rows[i].team = 0
        rows[i].fallen = False
        rows[i].penalized = False
        rows[i].subtype = class_subtype[rows[i].class_id]
    for q in range(len(robot_rows)):
        i = robot_rows[q]
        view = views[i]
        observer = view_observer[view]
        observer_is_robot = is_robot[observer]
        choices = len(others) - (1 if observer_is_robot else 0)
        pick = np.intp(pick_draws[q] * choices)
        if observer_is_robot and pick >= robots_before[observer]:
            pick += 1
        other = others[pick]
        src = view_frame[view] * objects + other
        rows[i].yaw = (yaw[src] - heading[view] + m * yaw_std * g[1, i] + math.pi) % (2 * math.pi) - math.pi
        rows[i].team = team[other] * observer_team[view]
        rows[i].fallen = fallen[src]
        rows[i].penalized = penalized[src]


def warm_up() -> None:
    """Compile (or load from the cache) every kernel once, on tiny inputs."""
    z, zi = np.zeros(2), np.zeros(2, np.int64)
    clip = line_clip(z, z, zi, z, z, z + 1, z, 0.5, 0.5, 1.0, True)
    v, k, ends, bits = line_visible(clip, z[:1], zi[:1], 1, 0.1, 2)
    line_miss(np.zeros((2, 1)), zi[:1], 1.0, True, 1.0, 1.0, 1.0)
    line_rows(np.zeros((2, 2, 1)), np.zeros((2, 1)), zi[:1], zi[:1], zi[:1], zi[:1], 1, 5)
    rows = np.zeros(1, _DETECTION)
    distance = np.zeros(1, np.float32)
    rows, order, offsets = sort_by_view(rows, zi[:1], distance.view(np.uint32), 1, -1)
    view = zi[:1]
    idx, ratio, x, y = sighting_inputs(rows, distance, np.ones(256, np.bool_), np.zeros(256))
    sighting_bits(rows, view, distance, idx, ratio, ratio, x, y, 0.5, np.ones(256), np.ones(256, np.bool_), 1.0,
                  2, 4)
    confidence_exponents(rows, z[:1], 1.5, np.zeros(256))
    occ = np.zeros((1, 1), np.int64)
    for band in (False, True):
        hidden(zi[:1], zi[:1], zi[:1], z, z, z + 1, z, np.ones(2, np.bool_), occ, np.ones((1, 1), np.bool_), zi[:1],
               band, 0.2)
    px, py, in_range = rim_points(z, z, zi, zi, z, z, zi, z + 1, z, 1.0)
    rim_count(px, in_range, 0.5, 2)
    clamped_features(rows, 50.0)
    cx, cy = camera_offsets(z, z, zi, zi, zi, z, z)
    in_view, partial = in_view_partial(z, reach_ratio(z, z + 1), z, z + 1, 0.5, zi[:1])
    nb = np.zeros(2, np.bool_)
    at, jj, vv, dk, ck, near, distant, bits, xk, yk, visible = visible_pairs(zi, zi, nb, -1, zi, z, nb, z, z,
                                                                            np.zeros(1, np.uint8), z, 2, 1, 2)
    u, uf, table = np.zeros((4, 2)), np.ones(8), np.zeros(512)
    realistic_misses(z, z, zi, zi, zi[:0], 1, 1, 2, zi, zi, at, jj, bits, dk, near + 1, ck, distant, -1, uf, 4, 1.0,
                     1.0, 1.0, z, 0.1, u, True, table, np.arange(256).astype(np.uint8))
    r, b = polar_radius_bearing(z, u, z, 1.0, 0.1, 0.1, 0.1)
    polar_points(r, b, b)
    feet_and_errors(ck, ck, nb, z, bits, u, u, 1.0, 0.1, 0.1, True, 1.0, 0.1, 0.1, 2)
    i8, u8, i32 = np.zeros(2, np.int8), np.zeros(2, np.uint8), np.zeros(2, np.int32)
    point_rows(nb, nb, at, vv, jj, zi, ck, xk, yk, z, z, bits, z, z, i8, nb, nb, z, z, i8, u8, i32, u8, 2, 2)
    fv, fc, fr, fratio, fu2 = false_positive_draws(zi, np.zeros((3, 0)), u8, True, 0, z, z, z)
    rows = false_positive_rows(fc, fr, fr, false_positive_bearings(fu2, fratio, 0.5))
    dress_made_up(rows, fv, np.zeros((2, 0)), 1.0, 0.1, 0.1, z, u8, 2, zi[:0], z[:0], zi, zi, z, i8, nb, zi, zi, z, nb,
                  nb, i8, 2)
    observation_rewards(np.zeros((2, 3), np.bool_), zi, 1, zi[:1], 2, 3.0, 3, 0.1, 0.1, 0.1)


__all__ = ["line_clip", "line_visible", "line_miss", "line_rows", "sort_by_view", "clamped_features", "observation_rewards",
           "camera_offsets", "reach_ratio", "in_view_partial", "visible_pairs", "realistic_misses",
           "polar_radius_bearing", "polar_points", "feet_and_errors", "point_rows",
           "false_positive_draws", "false_positive_bearings", "false_positive_rows", "dress_made_up", "sighting_inputs", "sighting_bits",
           "confidence_exponents", "hidden", "rim_points", "rim_count", "warm_up"]


@numba.njit(cache=True)
def sighting_inputs(rows: np.ndarray, distance: np.ndarray, point_class: np.ndarray,
                    reach_radius: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The point reports (classes that get their sighting bits from themselves) of the sorted ``rows``: their
    indices, the arcsin argument of their reach (radius / distance, clamped to [0, 1]) and their x, y."""
    n = 0
    for i in range(len(rows)):
        if point_class[rows[i].class_id]:
            n += 1
    idx = np.empty(n, np.int64)
    ratio, x, y = np.empty(n), np.empty(n), np.empty(n)
    eps = np.float32(_EPS)
    r = 0
    for i in range(len(rows)):
        c = rows[i].class_id
        if not point_class[c]:
            continue
        idx[r] = i
        ratio[r] = _minimum(_maximum(reach_radius[c] / np.float64(_maximum(distance[i], eps)), 0.0), 1.0)
        x[r], y[r] = rows[i].x, rows[i].y
        r += 1
    return idx, ratio, x, y


@numba.njit(cache=True)
def sighting_bits(rows: np.ndarray, view: np.ndarray, distance: np.ndarray, idx: np.ndarray, reach: np.ndarray,
                  bearing: np.ndarray, x: np.ndarray, y: np.ndarray, half: float, class_near: np.ndarray,
                  dynamic_class: np.ndarray, nearby2: float, partial: int, nearby: int) -> None:
    """PARTIAL (|bearing| beyond the half view less the reach), DISTANT (beyond the class's near range) and NEARBY
    (within the nearby distance of another ball or robot report of the same view) of the point reports ``idx``."""
    n = len(idx)
    start = 0
    while start < n:
        vv = view[idx[start]]
        stop = start
        while stop < n and view[idx[stop]] == vv:
            stop += 1
        for p in range(start, stop):
            i = idx[p]
            c = rows[i].class_id
            b = partial if abs(bearing[p]) > half - reach[p] else 0
            if distance[i] > class_near[c]:
                b += 1
            for o in range(start, stop):
                if o != p and dynamic_class[rows[idx[o]].class_id]:
                    gx, gy = x[p] - x[o], y[p] - y[o]
                    if gx * gx + gy * gy < nearby2:
                        b += nearby
                        break
            rows[i].sighting = b
        start = stop


@numba.njit(cache=True)
def confidence_exponents(rows: np.ndarray, z: np.ndarray, separation: float, prior_logit: np.ndarray) -> np.ndarray:
    """−logit of each report's calibrated confidence from its standard normal ``z``: evidence z + d' when it is
    correct (a real object of its class), z when not."""
    out = np.empty(len(rows))
    half_sq = separation * separation / 2
    for i in range(len(rows)):
        c = rows[i].class_id
        correct = rows[i].true_id != -1 and rows[i].true_class == c
        zz = z[i] + separation * (1.0 if correct else 0.0)
        out[i] = -(prior_logit[c] + separation * zz - half_sq)
    return out
