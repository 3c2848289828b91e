"""Auditing a perception preset: can a learner tell false reports from real ones by anything but their geometry?

A report is *false* when no object stands behind it (a false positive) or its object has another class (a
confusion). ``leak_check`` fits two logistic regressions on one half of the frames and scores them on the other: one
on the geometry alone — where the report is, and how close it is to the frame's other ball and robot reports (the
information the paper's rule 4 puts there on purpose) — and one on the geometry plus the chosen extra features. A
preset leaks when the extra features raise the held-out AUC beyond the sampling error. ``tools/perception_statistics.py``
prints the figures docs/perception.md records; ``test/test_perception_leaks.py`` asserts them.

``driving_leak_check`` is the same audit for the driving scenario's car, pedestrian and obstacle reports (the
geometry: distance, bearing and the distance to the frame's nearest car or obstacle report, where rule 4 puts false
pedestrians); ``tools/driving_perception_statistics.py`` prints its figures, ``test/test_driving_perception_leaks.py``
asserts them. Both tests compute their expectations independently (``test/leak_reference.py``).
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from dynenv_ros.core.object_classes import ObjectClass
from dynenv_ros.perception.detections import FEATURE_COLUMNS, as_features

POINT_CLASSES = (ObjectClass.BALL, ObjectClass.ROBOT, ObjectClass.GOALPOST, ObjectClass.PENALTY_CROSS,
                 ObjectClass.LINE_CROSSING)
NON_GEOMETRIC_FEATURES = ("cos_yaw", "sin_yaw", "size_x", "size_y", "team", "subtype", "fallen", "penalized",
                          "distant", "partial", "nearby")
NEARBY_FEATURE_DISTANCE = 0.35
DRIVING_POINT_CLASSES = (ObjectClass.CAR, ObjectClass.PEDESTRIAN, ObjectClass.OBSTACLE)
DRIVING_CROWD_CLASSES = (ObjectClass.CAR, ObjectClass.OBSTACLE)
DRIVING_NON_GEOMETRIC_FEATURES = ("cos_yaw", "sin_yaw", "size_x", "size_y", "team", "subtype", "distant", "partial",
                                  "nearby")


def false_reports(rows: np.ndarray) -> np.ndarray:
    """(k,) bool: no object behind the report, or an object of another class."""
    false: np.ndarray = (rows["true_id"] == -1) | (rows["true_class"] != rows["class_id"])
    return false


def nearest_of(rows: np.ndarray, views: np.ndarray, classes: tuple[int, ...]) -> np.ndarray:
    """Distance from each report to the nearest other report of one of ``classes`` in its view (inf if none);
    ``views`` (k,) sorted, one id per view."""
    out = np.full(len(rows), np.inf)
    dynamic = np.flatnonzero(np.isin(rows["class_id"], classes))
    if not len(dynamic):
        return out
    first, last = np.searchsorted(dynamic, np.searchsorted(views, views)), np.searchsorted(
        dynamic, np.searchsorted(views, views, side="right"))
    x, y = rows["x"].astype(float), rows["y"].astype(float)
    for k in range(int((last - first).max())):
        at = first + k
        other = dynamic[np.minimum(at, len(dynamic) - 1)]
        gap = np.hypot(x - x[other], y - y[other])
        out = np.where((at < last) & (other != np.arange(len(rows))), np.minimum(out, gap), out)
    return out


def nearest_dynamic(rows: np.ndarray, views: np.ndarray) -> np.ndarray:
    """Distance from each report to the nearest other ball or robot report of its view (inf if none)."""
    return nearest_of(rows, views, (ObjectClass.BALL, ObjectClass.ROBOT))


def _standardised(columns: list[np.ndarray]) -> np.ndarray:
    """The columns that vary, standardised, after an intercept column."""
    x = np.column_stack(columns)
    mean, std = x.mean(axis=0), x.std(axis=0)
    varies = std > 0
    x = (x[:, varies] - mean[varies]) / std[varies]
    return np.column_stack((np.ones(len(x)), x))


def _design(rows: np.ndarray, near: np.ndarray, extra: tuple[str, ...]) -> np.ndarray:
    features = as_features(rows)
    d = np.hypot(rows["x"], rows["y"]).astype(float)
    b = np.abs(np.arctan2(rows["y"], rows["x"])).astype(float)
    n = np.minimum(near, 10.0)
    columns = []
    for cls in POINT_CLASSES:
        indicator = (rows["class_id"] == cls).astype(float)
        geometry = [np.ones(len(rows)), d, d ** 2, d ** 3, b, b ** 2, b ** 3, d * b, n, n ** 2,
                    n < NEARBY_FEATURE_DISTANCE]
        columns += [indicator * g for g in geometry]
        columns += [indicator * features[:, FEATURE_COLUMNS.index(name)] for name in extra]
    return _standardised(columns)


def _driving_design(rows: np.ndarray, near: np.ndarray, extra: tuple[str, ...]) -> np.ndarray:
    features = as_features(rows)
    d = np.hypot(rows["x"], rows["y"]).astype(float) / 68.0
    b = np.arctan2(rows["y"], rows["x"]).astype(float)
    n = np.minimum(near, 10.0) / 10.0
    columns = []
    for cls in DRIVING_POINT_CLASSES:
        indicator = (rows["class_id"] == cls).astype(float)
        geometry = [np.ones(len(rows)), d, d ** 2, d ** 3, np.cos(b), np.sin(b), np.cos(2 * b), n, n ** 2,
                    near < 2.0, near < 4.0]
        columns += [indicator * g for g in geometry]
        columns += [indicator * features[:, FEATURE_COLUMNS.index(name)] for name in extra]
    return _standardised(columns)


def _logistic_fit(x: np.ndarray, y: np.ndarray, ridge: float = 1e-3, iterations: int = 10) -> np.ndarray:
    w = np.zeros(x.shape[1])
    for _ in range(iterations):                          # Newton's method on the ridge-penalised log-likelihood
        p = 1.0 / (1.0 + np.exp(-x @ w))
        hessian = (x * (p * (1 - p))[:, None]).T @ x + ridge * np.eye(len(w))
        w -= np.linalg.solve(hessian, x.T @ (p - y) + ridge * w)
    return w


def auc(score: np.ndarray, label: np.ndarray) -> float:
    """Area under the ROC curve: P(a random positive scores above a random negative)."""
    ranks = np.empty(len(score))
    ranks[np.argsort(score, kind="stable")] = np.arange(1, len(score) + 1)
    positives = label.sum()
    return float((ranks[label].sum() - positives * (positives + 1) / 2) / (positives * (len(label) - positives)))


@dataclass
class LeakCheck:
    geometry_auc: float          # held-out AUC of the geometry alone: the chance level a learner starts from
    extended_auc: float          # ... with the extra features
    difference_se: float         # bootstrap standard error of the difference
    false_reports: int
    reports: int


def leak_check(rows: np.ndarray, views: np.ndarray, extra: tuple[str, ...] = NON_GEOMETRIC_FEATURES,
               bootstrap: int = 30, seed: int = 0) -> LeakCheck:
    """Point reports ``rows`` with their view ids ``views`` (sorted) → the two held-out AUCs (even views train,
    odd views test, so whole frames stay on one side)."""
    point = np.isin(rows["class_id"], POINT_CLASSES)
    rows, views = rows[point], views[point]
    return _held_out_check(rows, views, nearest_dynamic(rows, views), _design, tuple(extra), bootstrap, seed)


def driving_leak_check(rows: np.ndarray, views: np.ndarray,
                       extra: tuple[str, ...] = DRIVING_NON_GEOMETRIC_FEATURES, bootstrap: int = 30,
                       seed: int = 0) -> LeakCheck:
    """``leak_check`` for driving: the car, pedestrian and obstacle reports of ``rows`` (view ids ``views``,
    sorted), the geometry per class being the distance, the bearing and the distance to the view's nearest other
    car or obstacle report."""
    point = np.isin(rows["class_id"], DRIVING_POINT_CLASSES)
    rows, views = rows[point], views[point]
    near = nearest_of(rows, views, DRIVING_CROWD_CLASSES)
    return _held_out_check(rows, views, near, _driving_design, tuple(extra), bootstrap, seed)


def _held_out_check(rows: np.ndarray, views: np.ndarray, near: np.ndarray,
                    design: Callable[[np.ndarray, np.ndarray, tuple[str, ...]], np.ndarray], extra: tuple[str, ...],
                    bootstrap: int, seed: int) -> LeakCheck:
    """Fit the geometry-only and the geometry-plus-``extra`` regressions (``design(rows, near, columns)``) on the
    even views, score the odd ones; the AUCs and the bootstrap SE of their difference over the held-out reports."""
    label = false_reports(rows)
    train = views % 2 == 0
    scores = []
    for columns in ((), extra):
        x = design(rows, near, columns)
        scores.append(x[~train] @ _logistic_fit(x[train], label[train].astype(float)))
    test_label = label[~train]
    rng = np.random.default_rng(seed)
    differences = []
    for _ in range(bootstrap):
        pick = rng.integers(0, len(test_label), len(test_label))
        differences.append(auc(scores[1][pick], test_label[pick]) - auc(scores[0][pick], test_label[pick]))
    return LeakCheck(auc(scores[0], test_label), auc(scores[1], test_label), float(np.std(differences)),
                     int(label.sum()), len(rows))
