"""Compiled geometry of the driving perception (``driving_model.py``): the per-pair visibility, occlusion by
rotated boxes along three sight lines, and lane clipping, as numba kernels (``@njit(cache=True)``).

Each kernel does, pair by pair, the floating-point operations the numpy expressions they replace did, in the same
order. The noise, dressing, placing and assembling kernels (``pair_reports``, ``dress_rows``, ``place_made_up``,
``uniform_false_positives``, ``lane_reports``, ``finish_rows``) take cos, sin, atan2 and exp from libm where numpy
used its own; their outputs were compared with the numpy code's over 1,050 frames (2-10 cars, the three presets,
one and two teams, noise magnitudes 1-5) and were bit-identical. No kernel draws random numbers: every draw stays
in the caller's seeded ``numpy.random.Generator``; the caller draws each block (a (rows, count) uniform block is
the same numbers as that many row-long draws in turn) before the kernel that uses it, so a seed gives the same
reports as before.

The first call of each kernel compiles it (or loads it from ``__pycache__``, numba's cache, keyed on this file's
contents and the CPU), which ``warm_up()`` does once per process.
"""
from __future__ import annotations

import math

import numba
import numpy as np

from dynenv_ros.perception.detections import DETECTION_DTYPE as _DETECTION
from dynenv_ros.perception.row_kernels import sort_by_view

_EPS = 1e-9


@numba.njit(cache=True)
def _segment_hits_box(ox: float, oy: float, px: float, py: float, cx: float, cy: float, ux: float, uy: float, a: float,
                      b: float) -> bool:
    """Segment O→P crosses the box (centre c, unit axis u, half sizes a along u and b across): separating axes."""
    qx, qy = ox - cx, oy - cy
    rx, ry = px - cx, py - cy
    qu, qv = qx * ux + qy * uy, qy * ux - qx * uy
    ru, rv = rx * ux + ry * uy, ry * ux - rx * uy
    if min(qu, ru) > a or max(qu, ru) < -a or min(qv, rv) > b or max(qv, rv) < -b:
        return False
    Dx, Dy = px - ox, py - oy
    centre = abs(qy * Dx - qx * Dy)
    extent = a * abs(ux * Dy - uy * Dx) + b * abs(ux * Dx + uy * Dy)
    return centre <= extent


@numba.njit(cache=True)
def _three_lines(b0: bool, b1: bool, b2: bool, x0: float, y0: float, p0x: float, p0y: float, p1x: float, p1y: float,
                 p2x: float, p2y: float, cx: float, cy: float, ux: float, uy: float, a: float,
                 b: float) -> tuple[bool, bool, bool]:
    """The three sight lines from (x0, y0) already blocked, or-ed with whether this box blocks them."""
    b0 = b0 or _segment_hits_box(x0, y0, p0x, p0y, cx, cy, ux, uy, a, b)
    b1 = b1 or _segment_hits_box(x0, y0, p1x, p1y, cx, cy, ux, uy, a, b)
    b2 = b2 or _segment_hits_box(x0, y0, p2x, p2y, cx, cy, ux, uy, a, b)
    return b0, b1, b2


@numba.njit(cache=True)
def _sight_lines_blocked(vv: int, jj: int, tx: float, ty: float, ux: float, uy: float, thx: float, thy: float,
                         trr: float, tcls: int, ddx: float, ddy: float, d: float, ox: np.ndarray, oy: np.ndarray,
                         cars_present: np.ndarray, occ_x: np.ndarray, occ_y: np.ndarray, occ_ux: np.ndarray,
                         occ_uy: np.ndarray, occ_a: np.ndarray, occ_b: np.ndarray, occ_r: np.ndarray,
                         occ_kind: np.ndarray, occ_obj: np.ndarray, hides: np.ndarray, B: int) -> int:
    """How many of one target's three sight lines (centre, both outline edges) an occluder blocks (0..3)."""
    inv = 1.0 / max(d, _EPS)
    ex, ey = ddx * inv, ddy * inv
    w = thx * abs(ux * ey - uy * ex) + thy * abs(ux * ex + uy * ey) + trr
    nx, ny = -ey * w, ex * w
    p0x, p0y = tx + 0.0 * nx, ty + 0.0 * ny
    p1x, p1y = tx + nx, ty + ny
    p2x, p2y = tx + -nx, ty + -ny
    x0, y0 = ox[vv], oy[vv]
    b0 = b1 = b2 = False
    if hides[0, tcls]:
        for o in range(B):
            cx, cy, cux, cuy, a, b = occ_x[o], occ_y[o], occ_ux[o], occ_uy[o], occ_a[o], occ_b[o]
            b0, b1, b2 = _three_lines(b0, b1, b2, x0, y0, p0x, p0y, p1x, p1y, p2x, p2y, cx, cy, cux, cuy, a, b)
            if b0 and b1 and b2:
                return 3
    if hides[1, tcls] or hides[2, tcls]:
        n_cars = len(cars_present)
        for o in range(B, len(occ_x)):
            kind, obj = occ_kind[o], occ_obj[o]
            if not hides[kind, tcls] or obj == jj or obj == vv:
                continue
            if kind == 1 and not cars_present[o - B]:
                continue
            qx, qy = occ_x[o] - x0, occ_y[o] - y0
            along = qx * ex + qy * ey
            across = abs(qx * ey - qy * ex)
            R = occ_r[o]
            if not (along > -R and along < d + R and across < R + w):
                continue
            cx, cy, cux, cuy, a, b = occ_x[o], occ_y[o], occ_ux[o], occ_uy[o], occ_a[o], occ_b[o]
            b0, b1, b2 = _three_lines(b0, b1, b2, x0, y0, p0x, p0y, p1x, p1y, p2x, p2y, cx, cy, cux, cuy, a, b)
            if b0 and b1 and b2:
                return 3
        _ = n_cars
    return int(b0) + int(b1) + int(b2)


@numba.njit(cache=True)
def visible_pairs(X: np.ndarray, Y: np.ndarray, UX: np.ndarray, UY: np.ndarray, present: np.ndarray,
                  cars_present: np.ndarray, hx: np.ndarray, hy: np.ndarray, rr: np.ndarray, cls: np.ndarray,
                  max_range: np.ndarray, near: np.ndarray, ox: np.ndarray, oy: np.ndarray, c: np.ndarray, s: np.ndarray,
                  occ_x: np.ndarray, occ_y: np.ndarray, occ_ux: np.ndarray, occ_uy: np.ndarray, occ_a: np.ndarray,
                  occ_b: np.ndarray, occ_r: np.ndarray, occ_kind: np.ndarray, occ_obj: np.ndarray, hides: np.ndarray,
                  B: int, any_hides: bool, realistic: bool, n_cars: int, n_peds: int, nearby2: float,
                  factor: np.ndarray, range_offset: float, range_slope: float, range_reference: float,
                  visible: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Every (view v, object j) pair in range, present, not the observer and not hidden (fewer than three sight
    lines blocked), view after view, object after object: its index v·N + j, v, j, the offset in the observer's
    frame (x forward, y left), the distance, the sighting bits (PARTIAL if a sight line is blocked, DISTANT beyond the
    class's near range) and, in realistic mode, the miss multiplier (range term × the factor of the bits, NEARBY from
    the true positions: a pedestrian within the nearby distance of a car or obstacle other than the observer).
    Marks ``visible`` (V·N bools)."""
    V, N = len(ox), len(X)
    cap = V * N
    at = np.empty(cap, np.int64)
    vo = np.empty(cap, np.int64)
    jo = np.empty(cap, np.int64)
    xo = np.empty(cap)
    yo = np.empty(cap)
    do = np.empty(cap)
    bo = np.empty(cap, np.int64)
    mo = np.empty(cap)
    K = 0
    for v in range(V):
        x0, y0, cv, sv = ox[v], oy[v], c[v], s[v]
        for j in range(N):
            if j == v or not present[j]:
                continue
            dx, dy = X[j] - x0, Y[j] - y0
            d = math.hypot(dx, dy)
            if not d <= max_range[j]:
                continue
            blocked = 0
            if any_hides:
                blocked = _sight_lines_blocked(v, j, X[j], Y[j], UX[j], UY[j], hx[j], hy[j], rr[j], cls[j], dx, dy,
                                               d, ox, oy, cars_present, occ_x, occ_y, occ_ux, occ_uy, occ_a, occ_b,
                                               occ_r, occ_kind, occ_obj, hides, B)
            if blocked >= 3:
                continue
            visible[v * N + j] = True
            at[K], vo[K], jo[K], do[K] = v * N + j, v, j, d
            xo[K], yo[K] = cv * dx + sv * dy, cv * dy - sv * dx
            bits = (2 if blocked > 0 else 0) + (1 if d > near[j] else 0)           # PARTIAL 2, DISTANT 1
            bo[K] = bits
            if realistic:
                close = False
                if n_cars <= j < n_cars + n_peds:
                    for o in range(N):
                        if o == v or n_cars <= o < n_cars + n_peds or not present[o]:
                            continue
                        gx, gy = X[j] - X[o], Y[j] - Y[o]
                        if gx * gx + gy * gy < nearby2:
                            close = True
                            break
                r = d / range_reference
                mo[K] = (range_offset + range_slope * (r * r)) * factor[bits + (4 if close else 0)]
            K += 1
    return at[:K], vo[:K], jo[:K], xo[:K], yo[:K], do[:K], bo[:K], mo[:K]


@numba.njit(cache=True)
def clip_lanes(lanes: np.ndarray, len2: np.ndarray, ox: np.ndarray, oy: np.ndarray, c: np.ndarray, s: np.ndarray,
               R: float, min_length: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Each (view, lane) whose segment meets the circle of radius R about the observer for at least ``min_length``:
    view, lane, the clipped segment's ends in the observer's frame, PARTIAL if clipped, the point nearest the car,
    the clipped segment's squared length (≥ ε) and the nearest point's distance."""
    V, L = len(ox), len(lanes)
    cap = V * L
    lv = np.empty(cap, np.int64)
    lk = np.empty(cap, np.int64)
    out = np.empty((8, cap))
    bits = np.empty(cap, np.int64)
    K = 0
    for v in range(V):
        cc, ss, x0, y0 = c[v], s[v], ox[v], oy[v]
        for k in range(L):
            l0x, l0y, l1x, l1y = lanes[k, 0], lanes[k, 1], lanes[k, 2], lanes[k, 3]
            ax0, ay0 = l0x - x0, l0y - y0
            ax, ay = cc * ax0 + ss * ay0, cc * ay0 - ss * ax0
            ex0, ey0 = l1x - l0x, l1y - l0y
            ex, ey = cc * ex0 + ss * ey0, cc * ey0 - ss * ex0
            ln2 = len2[k]
            bb = ax * ex + ay * ey
            disc = bb * bb - ln2 * (ax * ax + ay * ay - R * R)
            root = math.sqrt(max(disc, 0.0))
            lo = max(0.0, (-bb - root) / ln2)
            hi = min(1.0, (-bb + root) / ln2)
            if not (disc > 0 and (hi - lo) * math.sqrt(ln2) >= min_length):
                continue
            sx, sy, tx, ty = ax + lo * ex, ay + lo * ey, ax + hi * ex, ay + hi * ey
            gx, gy = tx - sx, ty - sy
            g2 = max(gx * gx + gy * gy, _EPS)
            t = min(max(-(sx * gx + sy * gy) / g2, 0.0), 1.0)
            nx, ny = sx + t * gx, sy + t * gy
            lv[K], lk[K] = v, k
            bits[K] = 2 if (lo > _EPS or hi < 1 - _EPS) else 0
            out[0, K], out[1, K], out[2, K], out[3, K] = sx, sy, tx, ty
            out[4, K], out[5, K], out[6, K] = nx, ny, g2
            out[7, K] = math.hypot(nx, ny)
            K += 1
    return lv[:K], lk[:K], bits[:K], out[:, :K]


@numba.njit(cache=True)
def _order_ends(a: float, b: float, e: float, f: float, g2: float) -> tuple[float, float, float, float, float, float]:
    """One segment's ends in order (nearer end first; equally far: rear end first, then the right end) and the point
    nearest the car."""
    gap = math.hypot(e, f) - math.hypot(a, b)
    tie = abs(gap) <= 1e-6
    if gap < -1e-6 or (tie and e < a - 1e-6) or (tie and abs(e - a) <= 1e-6 and f < b):
        a, b, e, f = e, f, a, b
    gx, gy = e - a, f - b
    t = min(max(-(a * gx + b * gy) / g2, 0.0), 1.0)
    return a, b, e, f, a + t * gx, b + t * gy


@numba.njit(cache=True)
def lane_rows(lv: np.ndarray, k: np.ndarray, bits: np.ndarray, g: np.ndarray, noisy: bool, keep: np.ndarray,
              shift: np.ndarray, ct: np.ndarray, st: np.ndarray, same: np.ndarray, centre: np.ndarray,
              size_y: np.ndarray, n_views: int, lane_class: int, same_subtype: int, opposing_subtype: int,
              edge_subtype: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The lane reports of ``clip_lanes``' segments ``g`` (kept ones only when ``noisy``: shifted sideways by
    ``shift`` along the segment's normal and turned by the angle of cos ``ct``, sin ``st`` about the point nearest
    the car), ends ordered by ``_order_ends``; all fields but the yaw, whose direction (gx, gy) it returns; and the
    count per view."""
    K = len(lv)
    M = 0
    for i in range(K):
        if not noisy or keep[i]:
            M += 1
    rows = np.zeros(M, _DETECTION)
    gxo, gyo = np.empty(M), np.empty(M)
    seen = np.zeros(n_views, np.int64)
    r = 0
    for i in range(K):
        if noisy and not keep[i]:
            continue
        sx, sy, tx, ty, nx, ny, g2 = g[0, i], g[1, i], g[2, i], g[3, i], g[4, i], g[5, i], g[6, i]
        if noisy:
            gx, gy = tx - sx, ty - sy
            inv = 1.0 / math.sqrt(g2)
            px, py = -gy * inv * shift[i], gx * inv * shift[i]
            c, s = ct[i], st[i]
            rx, ry = sx - nx, sy - ny
            sx, sy = nx + px + c * rx - s * ry, ny + py + s * rx + c * ry
            rx, ry = tx - nx, ty - ny
            tx, ty = nx + px + c * rx - s * ry, ny + py + s * rx + c * ry
            gx, gy = tx - sx, ty - sy
            g2 = max(gx * gx + gy * gy, _EPS)
        a, b, e, f, qx, qy = _order_ends(sx, sy, tx, ty, g2)
        gxo[r], gyo[r] = e - a, f - b
        w = rows[r]
        w.class_id = lane_class
        w.x, w.y = qx, qy
        w.line_start_x, w.line_start_y, w.line_end_x, w.line_end_y = a, b, e, f
        w.size_x = math.sqrt(g2)
        w.size_y = size_y[k[i]]
        w.subtype = (same_subtype if same[i] else opposing_subtype) if centre[k[i]] else edge_subtype
        w.sighting = bits[i]
        w.true_id = -2 - k[i]
        w.true_class = lane_class
        seen[lv[i]] += 1
        r += 1
    return rows, gxo, gyo, seen


@numba.njit(cache=True)
def pair_rows(kept: np.ndarray, reported: np.ndarray, true_class: np.ndarray, xk: np.ndarray, yk: np.ndarray,
              size_factor: np.ndarray, yaw_noise: np.ndarray, v: np.ndarray, j: np.ndarray, bits: np.ndarray,
              hx: np.ndarray, hy: np.ndarray, rr: np.ndarray, yaw: np.ndarray, oyaw: np.ndarray, team: np.ndarray,
              n_cars: int, car: int) -> np.ndarray:
    """The reports of the kept (view, object) pairs: class as reported, position, size (× the size error), relative
    heading with its error and team relation (cars), sighting bits, the true object and class."""
    rows = np.zeros(len(kept), _DETECTION)
    for r in range(len(kept)):
        i = kept[r]
        jj, vv = j[i], v[i]
        w = rows[r]
        w.class_id = reported[i]
        w.x, w.y = xk[i], yk[i]
        f = size_factor[i]
        w.size_x = 2 * (hx[jj] + rr[jj]) * f
        w.size_y = 2 * (hy[jj] + rr[jj]) * f
        if true_class[i] == car:
            w.yaw = (yaw[jj] - oyaw[vv] + yaw_noise[i] + math.pi) % (2 * math.pi) - math.pi
            w.team = team[min(jj, n_cars - 1)] * team[vv]
        else:
            w.yaw = np.nan
        w.sighting = bits[i]
        w.true_id = jj
        w.true_class = true_class[i]
    return rows


@numba.njit(cache=True)
def lane_reports(lv: np.ndarray, k: np.ndarray, bits: np.ndarray, g: np.ndarray, noisy: bool, realistic: bool,
                 uniform: bool, u: np.ndarray, n2: np.ndarray, m: float, miss_rate: float, range_offset: float,
                 range_slope: float, range_reference: float, lateral_uniform: float, angle_uniform: float,
                 lateral_base: float, lateral_per_m2: float, angle_std: float, lane_heading: np.ndarray,
                 oyaw: np.ndarray, centre: np.ndarray, size_y: np.ndarray, n_views: int, lane_class: int,
                 same_subtype: int, opposing_subtype: int,
                 edge_subtype: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The lane reports of ``clip_lanes``' segments in one call: when ``noisy`` each one missed (``u[0]``) at the
    lane class's rate (``miss_rate`` = ρ x its scale, x the range factor when ``realistic``), shifted and turned
    (from ``u[1:3]`` when ``uniform``, else the normal draws ``n2``), then ``lane_rows``, the yaw of each report's
    direction (a painted line has no arrow: within ±π/2) and the view of each report."""
    K = len(lv)
    keep = np.ones(K, np.bool_)
    shift, ct, st = np.zeros(K), np.ones(K), np.zeros(K)
    if noisy:
        for i in range(K):
            dn = g[7, i]
            mult = range_offset + range_slope * (dn / range_reference) ** 2 if realistic else 1.0
            keep[i] = u[0, i] >= miss_rate * mult
            if uniform:
                shift[i] = (u[1, i] - 0.5) * m * lateral_uniform * mult
                turn = (u[2, i] - 0.5) * m * angle_uniform * mult
            else:
                shift[i] = n2[0, i] * m * (lateral_base + lateral_per_m2 * dn * dn)
                turn = n2[1, i] * m * angle_std
            ct[i], st[i] = math.cos(turn), math.sin(turn)
    same = np.empty(K, np.bool_)
    for i in range(K):
        same[i] = math.cos(lane_heading[k[i]] - oyaw[lv[i]]) >= 0
    rows, gx, gy, seen = lane_rows(lv, k, bits, g, noisy, keep, shift, ct, st, same, centre, size_y, n_views,
                                   lane_class, same_subtype, opposing_subtype, edge_subtype)
    views = np.empty(len(rows), np.int64)
    r = 0
    for i in range(K):
        if keep[i]:
            views[r] = lv[i]
            r += 1
    for r in range(len(rows)):
        rows[r].yaw = (math.atan2(gy[r], gx[r]) + math.pi / 2) % math.pi - math.pi / 2
    return rows, views, seen


UNIFORM_POSITION, GAUSSIAN_POSITION, POLAR_POSITION = 0, 1, 2     # ``pair_reports``' position error models


@numba.njit(cache=True)
def pair_reports(at: np.ndarray, v: np.ndarray, j: np.ndarray, xk: np.ndarray, yk: np.ndarray, dk: np.ndarray,
                 bits: np.ndarray, mult: np.ndarray, ck: np.ndarray, noisy: bool, realistic: bool, confusions: bool,
                 position_model: int, uniform_yaw: bool, u: np.ndarray, pos: np.ndarray, g: np.ndarray, yu: np.ndarray,
                 m: float, rho: float, class_scale: np.ndarray, confusion_rate: np.ndarray,
                 confusion_target: np.ndarray, uniform_scale: float, random_std: float, radial_base: float,
                 radial_per_m2: float, bearing_std: float, size_std: float, yaw_std: float, near_car_range: float,
                 near_car_probability: float, distant: int, partial: int, seen: np.ndarray, hx: np.ndarray,
                 hy: np.ndarray, rr: np.ndarray, yaw: np.ndarray, oyaw: np.ndarray, team: np.ndarray, n_cars: int,
                 car: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The reports of ``visible_pairs``' pairs in one call. When ``noisy``: each pair missed (``u[0]``) at its
    class's rate, confused (``u[1]``, ``realistic`` with ``confusions``) into its class's target, moved by the
    position error (``pos``: uniform draws for ``UNIFORM_POSITION``, normal ones otherwise), its size and heading
    errored (normal ``g``; the heading from the uniform ``yu`` when ``uniform_yaw``) and, ``realistic``, chosen
    (``u[2]``) to get a made-up pedestrian next to it when it is a nearby, unhidden car reported as a car. Marks
    ``seen`` (the flat (view, object) pairs reported as their own class); returns the rows (``pair_rows``), the
    kept pairs' indices, and per pair: confused, the near-car choice, and the errored position."""
    K = len(at)
    keep = np.ones(K, np.bool_)
    confused = np.zeros(K, np.bool_)
    near_car = np.zeros(K, np.bool_)
    reported = ck.copy()
    x, y = xk.copy(), yk.copy()
    size_factor, yaw_noise = np.ones(K), np.zeros(K)
    if noisy:
        for i in range(K):
            c = ck[i]
            f = mult[i] if realistic else 1.0
            keep[i] = u[0, i] >= rho * class_scale[c] * f
            if realistic and confusions:
                confused[i] = keep[i] and u[1, i] < confusion_rate[c + (bits[i] & distant) * 256] * f
                if confused[i]:
                    reported[i] = confusion_target[c]
            if position_model == UNIFORM_POSITION:
                scale = m * uniform_scale * f
                x[i] = xk[i] + (pos[0, i] - 0.5) * scale
                y[i] = yk[i] + (pos[1, i] - 0.5) * scale
            elif position_model == GAUSSIAN_POSITION:
                x[i] = xk[i] + pos[0, i] * m * random_std
                y[i] = yk[i] + pos[1, i] * m * random_std
            else:
                d = dk[i]
                r = max(0.0, d + pos[0, i] * m * (radial_base + radial_per_m2 * d * d))
                b = math.atan2(yk[i], xk[i]) + pos[1, i] * m * bearing_std
                x[i], y[i] = r * math.cos(b), r * math.sin(b)
            size_factor[i] = max(0.2, 1.0 + m * size_std * g[0, i])
            yaw_noise[i] = (yu[i] - 0.5) * m * yaw_std if uniform_yaw else g[1, i] * m * yaw_std
            if realistic:
                near_car[i] = (c == car and reported[i] == car and keep[i] and dk[i] < near_car_range
                               and (bits[i] & (distant | partial)) == 0 and u[2, i] < near_car_probability * m)
    n_kept = 0
    for i in range(K):
        if keep[i]:
            n_kept += 1
            if not confused[i]:
                seen[at[i]] = True
    kept = np.empty(n_kept, np.int64)
    r = 0
    for i in range(K):
        if keep[i]:
            kept[r] = i
            r += 1
    rows = pair_rows(kept, reported, ck, x, y, size_factor, yaw_noise, v, j, bits, hx, hy, rr, yaw, oyaw, team,
                     n_cars, car)
    return rows, kept, confused, near_car, x, y


@numba.njit(cache=True)
def dress_rows(rows: np.ndarray, v: np.ndarray, g: np.ndarray, ur: np.ndarray, oyaw: np.ndarray, yaw: np.ndarray,
               present: np.ndarray, half_length: np.ndarray, half_width: np.ndarray, team: np.ndarray,
               single_team: bool, uniform_yaw: bool, m: float, size_std: float, yaw_std: float,
               pedestrian_radius: float, obstacle_half: float, car: int, pedestrian: int) -> None:
    """Give reports that no object of their class stands behind (false positives, confusions) what a real report of
    that class has (``DrivingPerceiver._dressing`` says how), from the caller's draws: ``g`` (2, K) normal (size and
    heading error), ``ur`` (rows, cars) uniform — per car report: the other car it copies, the car type when there
    is none, the heading when there is none, then the heading error when ``uniform_yaw``, then the team when not
    ``single_team``."""
    present_cars = np.flatnonzero(present)
    P = len(present_cars)
    yaw_row = 3
    team_row = 4 if uniform_yaw else 3
    c = 0                                                      # the car reports' running index (ur's column)
    for i in range(len(rows)):
        r = rows[i]
        f = max(0.2, 1.0 + m * size_std * g[0, i])
        r.yaw = np.nan
        r.team = 0
        r.subtype = 0
        size = (2 * pedestrian_radius if r.class_id == pedestrian else 2 * obstacle_half) * f
        r.size_x = size
        r.size_y = r.size_x
        if r.class_id != car:
            continue
        vc = v[i]
        own = present[vc]
        choices = P - (1 if own else 0)
        pick = np.int64(ur[0, c] * max(choices, 1))
        if own and pick >= np.searchsorted(present_cars, vc):
            pick += 1
        none = choices <= 0
        other = present_cars[min(pick, max(P - 1, 0))] if P else 0  # type: ignore[call-overload]  # np.int64 pick
        src = np.int64(ur[1, c] * len(half_length)) if none else other
        r.size_x = 2 * half_length[src] * f
        r.size_y = 2 * half_width[src] * f
        rel = (ur[2, c] * 2 - 1) * math.pi if none else yaw[src] - oyaw[vc]
        noise = (ur[yaw_row, c] - 0.5) * m * yaw_std if uniform_yaw else g[1, i] * m * yaw_std
        r.yaw = (rel + noise + math.pi) % (2 * math.pi) - math.pi
        relation = team[src] * team[vc]
        if not single_team and none:
            relation = -1 if ur[team_row, c] < 0.5 else 1
        r.team = relation
        c += 1


@numba.njit(cache=True)
def place_made_up(rows: np.ndarray, v: np.ndarray, g: np.ndarray, ur: np.ndarray, oyaw: np.ndarray, yaw: np.ndarray,
                  present: np.ndarray, half_length: np.ndarray, half_width: np.ndarray, team: np.ndarray,
                  single_team: bool, uniform_yaw: bool, m: float, size_std: float, yaw_std: float,
                  pedestrian_radius: float, obstacle_half: float, car: int, pedestrian: int, ox: np.ndarray,
                  oy: np.ndarray, c: np.ndarray, s: np.ndarray, occ_x: np.ndarray, occ_y: np.ndarray,
                  occ_ux: np.ndarray, occ_uy: np.ndarray, occ_a: np.ndarray, occ_b: np.ndarray, occ_r: np.ndarray,
                  occ_kind: np.ndarray, occ_obj: np.ndarray, hides: np.ndarray, B: int, any_hides: bool,
                  class_max: np.ndarray, partial: int) -> tuple[np.ndarray, np.ndarray]:
    """Made-up reports dressed (``dress_rows``, same draws), then only those a real object of their class could be
    seen at (within its range, fewer than three sight lines blocked), PARTIAL when any is: the rows and their views."""
    dress_rows(rows, v, g, ur, oyaw, yaw, present, half_length, half_width, team, single_team, uniform_yaw, m,
               size_std, yaw_std, pedestrian_radius, obstacle_half, car, pedestrian)
    K = len(rows)
    blocked = np.zeros(K, np.int64)
    ok = np.zeros(K, np.bool_)
    for i in range(K):
        r = rows[i]
        x, y = np.float64(r.x), np.float64(r.y)
        d = math.hypot(x, y)
        vv = v[i]
        wx, wy = c[vv] * x - s[vv] * y, s[vv] * x + c[vv] * y       # world offsets
        if any_hides:
            yaw_world = 0.0
            if r.class_id == car:
                ry = np.float64(r.yaw)
                yaw_world = (0.0 if np.isnan(ry) else ry) + oyaw[vv]
            hx, hy = np.float64(r.size_x) / 2, np.float64(r.size_y) / 2
            ped = r.class_id == pedestrian
            blocked[i] = _sight_lines_blocked(vv, -1, ox[vv] + wx, oy[vv] + wy, math.cos(yaw_world),
                                              math.sin(yaw_world), 0.0 if ped else hx, 0.0 if ped else hy,
                                              hx if ped else 0.0, r.class_id, wx, wy, d, ox, oy, present, occ_x,
                                              occ_y, occ_ux, occ_uy, occ_a, occ_b, occ_r, occ_kind, occ_obj, hides, B)
        ok[i] = blocked[i] < 3 and d <= class_max[r.class_id]
    keep = np.flatnonzero(ok)
    out = np.empty(len(keep), rows.dtype)
    views = np.empty(len(keep), np.int64)
    for k in range(len(keep)):
        out[k] = rows[keep[k]]
        out[k].sighting = partial if blocked[keep[k]] > 0 else 0
        views[k] = v[keep[k]]
    return out, views


@numba.njit(cache=True)
def uniform_false_positives(counts: np.ndarray, u: np.ndarray, classes: np.ndarray, max_range: np.ndarray,
                            unknown: int) -> tuple[np.ndarray, np.ndarray]:
    """The uniform false positives of each view (``counts[v]`` chances that came up): class ``classes[u[0]]`` (an
    ``unknown`` one is dropped), distance ``u[1]`` x the class's ``max_range``, bearing from ``u[2]`` all round; the
    rows (class and position only) and their views."""
    total = 0
    for v in range(len(counts)):
        total += counts[v]
    cls = np.empty(total, np.uint8)
    views = np.empty(total, np.int64)
    M = 0
    k = 0
    for v in range(len(counts)):
        for _ in range(counts[v]):
            c = classes[np.int64(u[0, k] * len(classes))]
            if c != unknown:
                cls[k], views[k] = c, v
                M += 1
            else:
                cls[k], views[k] = unknown, -1
            k += 1
    rows = np.zeros(M, _DETECTION)
    out_views = np.empty(M, np.int64)
    r = 0
    for k in range(total):
        if views[k] < 0:
            continue
        radius = u[1, k] * max_range[cls[k]]
        bearing = (u[2, k] * 2 - 1) * math.pi
        rows[r].class_id = cls[k]
        rows[r].x, rows[r].y = radius * math.cos(bearing), radius * math.sin(bearing)
        out_views[r] = views[k]
        r += 1
    return rows, out_views


# -- records (DETECTION_DTYPE rows written field by field; ``rows`` come zeroed) -------------------------------------
@numba.njit(cache=True)
def self_rows(rows: np.ndarray, ego: np.ndarray, goal_x: np.ndarray, goal_y: np.ndarray, ox: np.ndarray, oy: np.ndarray,
              c: np.ndarray, s: np.ndarray, speed: np.ndarray, yaw_rate: np.ndarray, g: np.ndarray, noisy: bool,
              m: float, speed_std: float, yaw_rate_std: float, goal_std: float, half_length: np.ndarray,
              half_width: np.ndarray, crashed: np.ndarray, finished: np.ndarray, self_class: int) -> None:
    """One SELF row per car (goal in its own frame, speed and yaw rate, with the self-state noise ``g`` (4, V) when
    ``noisy``) and its ego values (float32 EGO_COLUMNS)."""
    for v in range(len(ox)):
        gx, gy = goal_x[v] - ox[v], goal_y[v] - oy[v]
        ax, ay = c[v] * gx + s[v] * gy, c[v] * gy - s[v] * gx
        sp, yr = speed[v], yaw_rate[v]
        if noisy:
            sp = sp + g[0, v] * m * speed_std
            yr = yr + g[1, v] * m * yaw_rate_std
            ax = ax + g[2, v] * m * goal_std
            ay = ay + g[3, v] * m * goal_std
        r = rows[v]
        r.class_id = self_class
        r.x, r.y = ax, ay
        r.yaw = np.nan
        r.size_x, r.size_y = 2 * half_length[v], 2 * half_width[v]
        r.confidence = 1.0
        r.fallen, r.penalized = crashed[v], finished[v]
        r.line_start_x, r.line_start_y = sp, yr
        r.true_id = v
        r.true_class = self_class
        ego[v, 0], ego[v, 1], ego[v, 2], ego[v, 3] = sp, yr, ax, ay
        ego[v, 4], ego[v, 5] = r.size_x, r.size_y
        ego[v, 6], ego[v, 7] = crashed[v], finished[v]


@numba.njit(cache=True)
def sighting_bits(rows: np.ndarray, distance: np.ndarray, offsets: np.ndarray, class_near: np.ndarray, nearby2: float,
                  car: int, pedestrian: int, obstacle: int, distant: int, partial: int, nearby: int) -> None:
    """DISTANT and NEARBY of the sorted reports from the reports themselves, by one rule for real and made-up ones:
    DISTANT beyond the class's near range, NEARBY a pedestrian within the nearby distance of a reported car or
    obstacle of the same view (PARTIAL kept)."""
    for v in range(len(offsets) - 1):
        for i in range(offsets[v], offsets[v + 1]):
            cls = rows[i].class_id
            if cls == car or cls == pedestrian or cls == obstacle:
                b = rows[i].sighting & partial
                if distance[i] > class_near[cls]:
                    b |= distant
                rows[i].sighting = b
        for i in range(offsets[v], offsets[v + 1]):
            if rows[i].class_id != pedestrian:
                continue
            for o in range(offsets[v], offsets[v + 1]):
                cls = rows[o].class_id
                if cls != car and cls != obstacle:
                    continue
                dx = np.float64(rows[i].x - rows[o].x)
                dy = np.float64(rows[i].y - rows[o].y)
                if dx ** 2 + dy ** 2 < nearby2:
                    rows[i].sighting |= nearby
                    break


@numba.njit(cache=True)
def finish_rows(rows: np.ndarray, view: np.ndarray, distance: np.ndarray, n_views: int, self_class: int,
                class_near: np.ndarray, nearby2: float, car: int, pedestrian: int, obstacle: int, distant: int,
                partial: int, nearby: int, z: np.ndarray, separation: float, prior_logit: np.ndarray,
                calibrated: bool) -> tuple[np.ndarray, np.ndarray]:
    """The frame's last pass in one call: rows sorted view after view (``sort_by_view``), their DISTANT and NEARBY
    bits (``sighting_bits``) and their confidence: the calibrated detector score of docs/perception.md from the
    standard normal draws ``z`` (one per sorted row, drawn by the caller), 1 for SELF rows or when not
    ``calibrated``. Returns the sorted rows and each view's first row (n_views + 1)."""
    rows, order, offsets = sort_by_view(rows, view, distance.view(np.uint32), n_views, self_class)
    sighting_bits(rows, distance[order], offsets, class_near, nearby2, car, pedestrian, obstacle, distant, partial,
                  nearby)
    half = separation * separation / 2
    for i in range(len(rows)):
        cls = rows[i].class_id
        if not calibrated or cls == self_class:
            rows[i].confidence = 1.0
            continue
        score = z[i]
        if rows[i].true_id != -1 and rows[i].true_class == cls:
            score += separation
        rows[i].confidence = 1.0 / (1.0 + math.exp(-(prior_logit[cls] + separation * score - half)))
    return rows, offsets


def warm_up() -> None:
    """Compile (or load from the cache) every kernel once, on tiny inputs."""
    z = np.zeros(1)
    zi = np.zeros(1, np.int64)
    hides = np.zeros((3, 256), np.bool_)
    occ = (z, z, z + 1, z, z + 1, z + 1, z + 1, zi, zi - 1)
    visible_pairs(z, z, z, z, np.ones(1, np.bool_), np.ones(1, np.bool_), z, z, z, np.zeros(1, np.uint8), z + 1,
                  z + 1, z, z, z + 1, z, *occ, hides, 1, False, False, 1, 0, 1.0, np.ones(8), 1.0, 0.0, 1.0,
                  np.zeros(1, np.bool_))
    clip_lanes(np.zeros((1, 4)), z + 1, z, z, z + 1, z, 1.0, 0.0)
    u8 = np.zeros(1, np.uint8)
    for model in (UNIFORM_POSITION, GAUSSIAN_POSITION, POLAR_POSITION):
        for flag in (True, False):
            pair_reports(zi, zi, zi, z, z, z + 1, zi, z + 1, u8, flag, flag, flag, model, flag, np.ones((4, 1)),
                         np.ones((2, 1)), np.ones((2, 1)), z, 1.0, 0.1, np.ones(256), np.zeros(512),
                         np.arange(256, dtype=np.uint8), 1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 0.1, 1, 2,
                         np.zeros(1, np.bool_), z, z, z, z, z, np.zeros(1, np.int8), 1, 1)
    uniform_false_positives(zi + 1, np.ones((3, 1)) / 2, np.ones(1, np.uint8), np.ones(256), 0)
    rows = np.zeros(1, _DETECTION)
    dressing = (zi, np.ones((2, 1)), np.ones((5, 1)), z, z, np.ones(1, np.bool_), z + 1, z + 1, np.ones(1, np.int8))
    for flag in (True, False):
        dress_rows(rows, *dressing, flag, flag, 1.0, 1.0, 1.0, 1.0, 1.0, 1, 2)
        place_made_up(rows, *dressing, flag, flag, 1.0, 1.0, 1.0, 1.0, 1.0, 1, 2, z, z, z + 1, z, *occ, hides, 1,
                      flag, np.ones(256), 2)
    self_rows(rows, np.zeros((1, 8), np.float32), z, z, z, z, z + 1, z, z, z, np.zeros((4, 1)), True, 1.0, 1.0, 1.0,
              1.0, z + 1, z + 1, np.zeros(1, np.bool_), np.zeros(1, np.bool_), 0)
    finish_rows(rows, zi, np.zeros(1, np.float32), 1, 0, np.ones(256), 1.0, 1, 2, 3, 1, 2, 4, z, 1.0, np.zeros(256),
                True)
    f = np.ones(1, np.bool_)
    for noisy in (True, False):
        for uniform in (True, False):
            lane_reports(zi, zi, zi, np.ones((8, 1)), noisy, True, uniform, np.ones((3, 1)), np.ones((2, 1)), 1.0,
                         0.1, 1.0, 0.0, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0, z, z, f, z + 1, 1, 0, 0, 0, 0)


# lane_rows, pair_rows and sighting_bits are steps of lane_reports, pair_reports and finish_rows, compiled inside them.
__all__ = ["visible_pairs", "clip_lanes", "lane_reports", "pair_reports", "dress_rows",
           "place_made_up", "uniform_false_positives", "self_rows", "finish_rows", "UNIFORM_POSITION",
           "GAUSSIAN_POSITION", "POLAR_POSITION", "warm_up"]
