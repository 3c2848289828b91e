"""Compiled steps both scenarios' perception share (``soccer_kernels``, ``driving_kernels`` re-export them).

Same rules as those modules: the floating-point operations of the numpy code they replace, no random draws.
"""
from __future__ import annotations

import numba
import numpy as np


@numba.njit(cache=True)
def sort_by_view(rows, view, distance_bits, n_views, first_class):
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
