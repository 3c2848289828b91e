"""Compiled steps both scenarios' perception share (``soccer_kernels``, ``driving_kernels`` re-export them).

Same rules as those modules: the floating-point operations of the numpy code they replace, no random draws.
"""
from __future__ import annotations

import math

import numba
import numpy as np


@numba.njit(cache=True)
def sort_by_view(rows: np.ndarray, view: np.ndarray, distance_bits: np.ndarray, n_views: int,
                 first_class: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rows view after view, each view's rows of ``first_class`` first (driving's SELF row; -1: none), then
    nearest first, stably; the order taken and each view's first row (``offsets``, n_views + 1). The bits of a
    non-negative float32 distance order as the distance does, so one integer key sorts by both."""
    M = len(rows)
    key = np.empty(M, np.int64)
    for i in range(M):
        not_first = 0 if rows[i].class_id == first_class else 1
        key[i] = (view[i] << 33) | (not_first << 32) | np.int64(distance_bits[i])
    order = np.argsort(key, kind="mergesort")
    out = np.empty(M, rows.dtype)
    sorted_view = np.empty(M, np.int64)
    for i in range(M):
        out[i] = rows[order[i]]
        sorted_view[i] = view[order[i]]
    offsets = np.empty(n_views + 1, np.int64)
    k = 0
    for v in range(n_views + 1):
        while k < M and sorted_view[k] < v:
            k += 1
        offsets[v] = k
    return out, order, offsets


@numba.njit(cache=True)
def _cos_sin(yaw: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """cos/sin of the yaws taken in float64 (driving's rows: within one float32 ulp of numpy's float32 cos/sin)."""
    cos_yaw, sin_yaw = np.empty(len(yaw)), np.empty(len(yaw))
    for i in range(len(yaw)):
        value = np.float64(yaw[i])
        cos_yaw[i], sin_yaw[i] = math.cos(value), math.sin(value)
    return cos_yaw, sin_yaw


@numba.njit(cache=True)
def _feature_rows(rows: np.ndarray, cos_yaw: np.ndarray, sin_yaw: np.ndarray, bound: float | np.float32
                  ) -> np.ndarray:
    """``np.clip(detections.as_features(rows), -bound, bound)`` with the yaws' cos/sin given: the columns of
    ``detections.FEATURE_COLUMNS``, yaw as cos/sin (0, 0 where undefined), the low three sighting bits as 0/1."""
    out = np.empty((len(rows), 19), np.float32)
    for i in range(len(rows)):
        r = rows[i]
        out[i, 0] = r.class_id
        out[i, 1], out[i, 2] = r.x, r.y
        if np.isfinite(r.yaw):
            out[i, 3], out[i, 4] = cos_yaw[i], sin_yaw[i]
        else:
            out[i, 3], out[i, 4] = 0.0, 0.0
        out[i, 5], out[i, 6], out[i, 7] = r.size_x, r.size_y, r.confidence
        out[i, 8], out[i, 9] = r.team, r.subtype
        out[i, 10], out[i, 11] = r.fallen, r.penalized
        out[i, 12], out[i, 13], out[i, 14], out[i, 15] = r.line_start_x, r.line_start_y, r.line_end_x, r.line_end_y
        bits = r.sighting
        out[i, 16], out[i, 17], out[i, 18] = bits & 1, (bits >> 1) & 1, (bits >> 2) & 1
        for k in range(19):
            value = out[i, k]                       # np.clip's maximum then minimum, NaN kept
            value = value if (value > -bound or value != value) else -bound
            out[i, k] = value if (value < bound or value != value) else bound
    return out


def clipped_features(rows: np.ndarray, bound: float) -> np.ndarray:
    """``detections.as_features(rows)`` clipped to ±``bound`` in one compiled pass, the yaws' cos/sin taken in
    float64 and rounded (within one float32 ulp of numpy's float32 cos/sin): driving's feature rows."""
    cos_yaw, sin_yaw = _cos_sin(rows["yaw"])
    return _feature_rows(rows, cos_yaw, sin_yaw, float(bound))


def clamped_features(rows: np.ndarray, bound: float) -> np.ndarray:
    """``np.clip(detections.as_features(rows), -bound, bound)`` to the bit, in one compiled pass and numpy's float32
    cos/sin of the yaws (so, unlike ``clipped_features``, no ulp apart): the soccer observation's feature rows."""
    yaw = rows["yaw"]
    bound32 = np.float32(bound)
    if float(bound32) != bound:
        raise ValueError(f"bound {bound!r} is not a float32: np.clip would compare in float64")
    return _feature_rows(rows, np.cos(yaw), np.sin(yaw), bound32)
