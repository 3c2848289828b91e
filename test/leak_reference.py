"""Independent reference computations of the perception leak audits, shared by test/test_perception_leaks.py and
test/test_driving_perception_leaks.py: each step written out differently from ``dynenv_ros.perception.audit`` (whose
``leak_check`` and ``driving_leak_check`` the tests check against these), so a mistake there shows as a mismatch.

- labels from the simulator's ``true_id``/``true_class``;
- the distance to the nearest report of some classes by brute force over every pair of each view;
- the AUC by counting pairs (ties count one half);
- ridge-penalised logistic regressions fitted by scipy's exact trust-region method;
- the bootstrap standard error of the difference of two held-out AUCs.
"""
from __future__ import annotations

from typing import Sequence

import numpy as np
from scipy.optimize import minimize


def false_mask(rows: np.ndarray) -> np.ndarray:
    """False or confused: no object behind the report (``true_id`` −1), or an object of another class."""
    return (rows["true_id"] == -1) | (rows["true_class"] != rows["class_id"])


def nearest_report(rows: np.ndarray, views: np.ndarray, classes: Sequence[int]) -> np.ndarray:
    """Distance from each report to the nearest other report of one of ``classes`` in its view (inf if none),
    every pair of every view (``views`` sorted) compared."""
    out = np.full(len(rows), np.inf)
    x, y = rows["x"].astype(float), rows["y"].astype(float)
    chosen = np.isin(rows["class_id"], classes)
    for at in np.split(np.arange(len(rows)), np.flatnonzero(np.diff(views)) + 1):
        others = at[chosen[at]]
        if len(others):
            gap = np.hypot(x[at, None] - x[others], y[at, None] - y[others])
            gap[at[:, None] == others] = np.inf
            out[at] = gap.min(axis=1)
    return out


def pair_auc(score: np.ndarray, positive: np.ndarray) -> float:
    """P(a positive scores above a negative) + ½·P(a tie), by counting for each positive the negatives below it and
    level with it."""
    negatives, positives = np.sort(score[~positive]), score[positive]
    below = np.searchsorted(negatives, positives, side="left")
    level = np.searchsorted(negatives, positives, side="right") - below
    return float((below.sum() + 0.5 * level.sum()) / (len(positives) * len(negatives)))


def standardised(columns: Sequence[np.ndarray]) -> np.ndarray:
    """The columns that vary, each standardised, after an intercept column."""
    x = np.column_stack(columns)
    varies = x.std(axis=0) > 0
    x = (x[:, varies] - x[:, varies].mean(axis=0)) / x[:, varies].std(axis=0)
    return np.column_stack((np.ones(len(x)), x))


def held_out_scores(x: np.ndarray, label: np.ndarray, train: np.ndarray, ridge: float = 1e-3) -> np.ndarray:
    """Logistic regression fitted on the ``train`` rows (negative log-likelihood + ridge/2·|w|², minimised by
    scipy's exact trust-region method), its logits on the others."""
    xt, yt = x[train], label[train].astype(float)

    def objective(w):
        z = xt @ w
        return (np.sum(np.logaddexp(0.0, z) - yt * z) + 0.5 * ridge * w @ w,
                xt.T @ (1.0 / (1.0 + np.exp(-z)) - yt) + ridge * w)

    def hessian(w):
        p = 1.0 / (1.0 + np.exp(-(xt @ w)))
        return (xt * (p * (1 - p))[:, None]).T @ xt + ridge * np.eye(len(w))

    fit = minimize(objective, np.zeros(x.shape[1]), jac=True, hess=hessian, method="trust-exact")
    assert fit.success, fit.message
    return x[~train] @ fit.x


def held_out_comparison(geometry_x: np.ndarray, everything_x: np.ndarray, label: np.ndarray, train: np.ndarray,
                        bootstrap: int = 30, seed: int = 0) -> tuple[float, float, float]:
    """(held-out AUC of the geometry, of the geometry plus the other features, bootstrap SE of their difference
    over the held-out reports)."""
    geometry_score, everything_score = (held_out_scores(x, label, train) for x in (geometry_x, everything_x))
    test = label[~train]
    rng = np.random.default_rng(seed)
    differences = []
    for _ in range(bootstrap):
        pick = rng.integers(0, len(test), len(test))
        differences.append(pair_auc(everything_score[pick], test[pick]) - pair_auc(geometry_score[pick], test[pick]))
    return pair_auc(geometry_score, test), pair_auc(everything_score, test), float(np.std(differences))


__all__ = ["false_mask", "nearest_report", "pair_auc", "standardised", "held_out_scores", "held_out_comparison"]
