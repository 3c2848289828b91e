"""Metrics of the self-supervised localization and reconstruction heads (pure numpy, no torch).

Three families, all over flat batches of "robot-steps" (one robot at one observation; callers flatten their
(sequence, time, robot) axes into the leading N axis):

``localization_fractions``
    The fraction of robot-steps whose estimated position lies within each distance threshold of the true one.
    This is what the DynEnv paper's Table 3 reports as localization "AP" (its code: the "corr" statistic,
    docs/original.md §9.6).

``detection_ap`` — a real average precision, as for object detectors (PASCAL VOC 2010+ / COCO style)
    Every predicted slot of every robot-step is one detection with a confidence. Detections are ranked by
    confidence over the whole set; going down the ranking, a detection is a true positive if it lies within the
    threshold of a *known* true object (seen at least once so far) of its class in the same robot-step that no
    higher-ranked detection has matched yet (it takes the nearest such object); otherwise it is a false positive —
    so a duplicate of an already-matched object is a false positive, and so is a confident slot where no known
    object is (the model claims something it cannot know). Recall is over the known true objects. AP is the area
    under the precision–recall curve with all-point interpolation: precision is replaced by its monotone envelope
    p̂(r) = max_{r' ≥ r} p(r') and AP = Σ_k (r_k − r_{k−1}) p̂(r_k). Detections of equal confidence are one
    operating point (the curve has a point only after the whole tie group), so the result never depends on how
    ties happen to be ordered; within one robot-step, tied detections are matched in slot order. Variant
    (``ignore_unknown=True``): detections near a true object that is not known yet are left out instead of being
    false positives (COCO's "ignore" rule) — the AP consistent with the reconstruction loss's own ignore rule.

``original_ap`` — DynEnv's "AP" (``ReconLosses.update_stats/compute_APs``, docs/original.md §9.6), kept to compare with
    the paper: at confidence > 0.5, precision = confident slots within the threshold of ANY true object of the class
    (known or not) / confident slots; recall = known objects whose ASSIGNED slot (the anchor assignment of the
    reconstruction loss) is within the threshold of that object and confident / known objects; "AP" = (P + R)/2.
    Counts are summed over the whole set before the ratios. The original's thresholds are 2× the paper's labels
    (52, 104, 208 cm for "25 cm, 50 cm, 1 m", docs/original.md §12.19): ``ORIGINAL_RECON_THRESHOLDS``.

Shapes used throughout: predicted positions ``pred_xy`` (N, S, 2) (S slots), confidences ``confidence`` (N, S) as
probabilities in [0, 1] (any monotone score works for the ranking of ``detection_ap``; thresholds need
probabilities), true positions ``true_xy`` (N, M, 2), ``known`` (N, M) bool. Distances are Euclidean in the units
of the positions (metres here); "within" means strictly less than the threshold.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping, Sequence

import numpy as np

THRESHOLDS = (0.25, 0.5, 1.0)                         # m: the paper's labels
ORIGINAL_RECON_THRESHOLDS = (0.52, 1.04, 2.08)        # m: what DynEnv's reconstruction "AP" really used
ORIGINAL_LOCALIZATION_THRESHOLDS = (0.26, 0.52, 1.04)  # m: what its localization "corr" really used


def threshold_name(metres: float) -> str:
    """'25cm', '50cm', '1m', '2.08m': the key of a threshold in metric dicts."""
    centimetres = round(metres * 100, 6)
    if centimetres < 100:
        return f"{centimetres:g}cm"
    return f"{metres:g}m"


def _check(pred_xy: np.ndarray, true_xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    pred_xy, true_xy = np.asarray(pred_xy, np.float64), np.asarray(true_xy, np.float64)
    if pred_xy.shape[-1] != 2 or true_xy.shape[-1] != 2:
        raise ValueError(f"positions must end in an axis of 2 (x, y), got {pred_xy.shape} and {true_xy.shape}")
    return pred_xy, true_xy


def localization_fractions(pred_xy: np.ndarray, true_xy: np.ndarray, thresholds: Sequence[float] = THRESHOLDS,
                           mask: np.ndarray | None = None) -> dict[str, float]:
    """{threshold name: fraction of robot-steps with ‖pred − true‖ < threshold}; pred_xy, true_xy (..., 2);
    ``mask`` (...) selects the robot-steps counted (default all). NaN where no robot-step is counted."""
    pred_xy, true_xy = _check(pred_xy, true_xy)
    error = np.linalg.norm(pred_xy - true_xy, axis=-1)
    if mask is not None:
        error = error[np.asarray(mask, bool)]
    error = error.reshape(-1)
    return {threshold_name(t): float(np.mean(error < t)) if error.size else float("nan") for t in thresholds}


@dataclass
class APResult:
    """One class at one threshold: ``ap``; the curve's operating points ``precision``, ``recall`` (one per
    distinct confidence, highest first) and their ``confidence``; ``true_positives`` and ``detections`` at the
    lowest confidence considered; ``objects`` = the known true objects (the recall denominator)."""
    ap: float
    precision: np.ndarray
    recall: np.ndarray
    confidence: np.ndarray
    true_positives: int
    detections: int
    objects: int


def match_detections(pred_xy: np.ndarray, confidence: np.ndarray, true_xy: np.ndarray, known: np.ndarray,
                     threshold: float) -> np.ndarray:
    """(N, S) bool: which detections are true positives under greedy matching (per robot-step, in decreasing
    confidence, ties in slot order, each detection takes the nearest known object within the threshold not yet
    taken)."""
    pred_xy, true_xy = _check(pred_xy, true_xy)
    confidence, known = np.asarray(confidence, np.float64), np.asarray(known, bool)
    N, S = confidence.shape
    if pred_xy.shape != (N, S, 2) or true_xy.shape[0] != N or known.shape != true_xy.shape[:2]:
        raise ValueError(f"shape mismatch: pred_xy {pred_xy.shape}, confidence {confidence.shape}, "
                         f"true_xy {true_xy.shape}, known {known.shape}")
    distance = np.linalg.norm(pred_xy[:, :, None, :] - true_xy[:, None, :, :], axis=-1)       # (N, S, M)
    candidate = (distance < threshold) & known[:, None, :]
    hit = np.zeros((N, S), bool)
    rows = np.flatnonzero(candidate.any(axis=(1, 2)))          # only robot-steps where some match is possible
    for n in rows:
        taken = np.zeros(true_xy.shape[1], bool)
        for s in np.argsort(-confidence[n], kind="stable"):
            free = candidate[n, s] & ~taken
            if free.any():
                m = int(np.argmin(np.where(free, distance[n, s], np.inf)))
                taken[m] = hit[n, s] = True
    return hit


def average_precision(hits: np.ndarray, confidence: np.ndarray, objects: int,
                      min_confidence: float | None = None) -> APResult:
    """AP of detections already marked true/false positive (``hits``, any shape, with ``confidence`` of the same
    shape) against ``objects`` known true objects. Detections with confidence below ``min_confidence`` (if given)
    are left out. No detection left, or no true positive: AP 0. No object: AP NaN (undefined)."""
    hits, confidence = np.asarray(hits, bool).reshape(-1), np.asarray(confidence, np.float64).reshape(-1)
    if hits.shape != confidence.shape:
        raise ValueError(f"hits {hits.shape} and confidence {confidence.shape} differ")
    if min_confidence is not None:
        keep = confidence >= min_confidence
        hits, confidence = hits[keep], confidence[keep]
    order = np.argsort(-confidence, kind="stable")
    hits, confidence = hits[order], confidence[order]
    tp = np.cumsum(hits)
    detections = np.arange(1, len(hits) + 1)
    # one operating point per distinct confidence: the end of each tie group
    last_of_group = np.flatnonzero(np.r_[confidence[1:] != confidence[:-1], True]) if len(hits) else np.array([], int)
    tp_points, det_points = tp[last_of_group], detections[last_of_group]
    precision = tp_points / np.maximum(det_points, 1)
    empty = np.array([], np.float64)
    if objects <= 0:
        return APResult(float("nan"), precision, np.full(len(precision), np.nan), confidence[last_of_group],
                        int(tp[-1]) if len(tp) else 0, len(hits), 0)
    recall = tp_points / objects
    if len(precision) == 0:
        return APResult(0.0, empty, empty, empty, 0, 0, objects)
    envelope = np.maximum.accumulate(precision[::-1])[::-1]
    steps = np.diff(np.r_[0.0, recall])
    ap = float(np.sum(steps * envelope))
    return APResult(ap, precision, recall, confidence[last_of_group], int(tp[-1]), len(hits), objects)


def detection_ap(pred_xy: np.ndarray, confidence: np.ndarray, true_xy: np.ndarray, known: np.ndarray,
                 threshold: float, min_confidence: float | None = None, ignore_unknown: bool = False,
                 present: np.ndarray | None = None) -> APResult:
    """The real AP of one class at one distance threshold (see the module docstring). pred_xy (N, S, 2),
    confidence (N, S), true_xy (N, M, 2), known (N, M) bool.

    ``ignore_unknown``: a detection that is no true positive but lies within the threshold of a true object that
    is not known yet (``present`` (N, M) bool says which rows are real objects, default all) is left out of the
    ranking — neither true nor false positive, as COCO's "ignore" ground truth. This is the AP that matches the
    reconstruction loss, which does not push down the confidence of a slot near an unseen object (it is there,
    so the slot is no false positive); the default (strict) AP counts such a slot as a false positive."""
    hits = match_detections(pred_xy, confidence, true_xy, known, threshold)
    confidence = np.asarray(confidence, np.float64)
    if ignore_unknown:
        pred_arr, true_arr = _check(pred_xy, true_xy)
        known_arr = np.asarray(known, bool)
        unknown = ~known_arr if present is None else (np.asarray(present, bool) & ~known_arr)
        distance = np.linalg.norm(pred_arr[:, :, None, :] - true_arr[:, None, :, :], axis=-1)
        keep = hits | ~((distance < threshold) & unknown[:, None, :]).any(-1)
        hits, confidence = hits[keep], confidence[keep]
    return average_precision(hits, confidence, int(np.asarray(known, bool).sum()), min_confidence)


@dataclass
class OriginalAP:
    """DynEnv's statistic at one threshold: ``precision``, ``recall``, ``ap`` = (precision + recall)/2 (NaN parts
    where a denominator is 0: precision with no confident slot is taken as 0, as a model that claims nothing
    finds nothing), with the counts behind them."""
    precision: float
    recall: float
    ap: float
    confident: int
    confident_near: int
    objects: int
    recalled: int


def original_ap(pred_xy: np.ndarray, confidence: np.ndarray, true_xy: np.ndarray, known: np.ndarray,
                assigned: np.ndarray, threshold: float, present: np.ndarray | None = None,
                confidence_threshold: float = 0.5) -> OriginalAP:
    """DynEnv's reconstruction "AP" of one class (module docstring). pred_xy (N, S, 2), confidence (N, S)
    probabilities, true_xy (N, M, 2) every true object of the class, known (N, M) bool seen-before, assigned
    (N, M) int the slot each object is assigned to (``dynenv_ros.agent.losses.assign_slots``; only read where
    known), present (N, M) bool which rows are real objects (default all)."""
    pred_xy, true_xy = _check(pred_xy, true_xy)
    confidence, known = np.asarray(confidence, np.float64), np.asarray(known, bool)
    assigned = np.asarray(assigned, np.int64)
    present = np.ones(known.shape, bool) if present is None else np.asarray(present, bool)
    confident = confidence > confidence_threshold                                              # (N, S)
    distance = np.linalg.norm(pred_xy[:, :, None, :] - true_xy[:, None, :, :], axis=-1)       # (N, S, M)
    near_any = ((distance < threshold) & present[:, None, :]).any(-1)
    n_confident = int(confident.sum())
    n_near = int((confident & near_any).sum())
    rows, objs = np.nonzero(known & present)
    slots = assigned[rows, objs]
    recalled = int(((distance[rows, slots, objs] < threshold) & confident[rows, slots]).sum())
    objects = len(rows)
    precision = n_near / n_confident if n_confident else 0.0
    recall = recalled / objects if objects else float("nan")
    return OriginalAP(precision, recall, (precision + recall) / 2, n_confident, n_near, objects, recalled)


def _nanmean(values: Sequence[float]) -> float:
    finite = [v for v in values if np.isfinite(v)]
    return float(np.mean(finite)) if finite else float("nan")


def reconstruction_report(classes: Mapping[str, Mapping[str, np.ndarray]],
                          thresholds: Sequence[float] = THRESHOLDS,
                          original_thresholds: Sequence[float] = ORIGINAL_RECON_THRESHOLDS) -> dict[str, dict]:
    """Both reconstruction metrics for several classes. ``classes`` maps a class name to a dict with pred_xy,
    confidence, true_xy, known and (for the original's statistic) assigned, optionally present. Returns
    {"ap": {class or "mean": {threshold name: AP}}, "ap_ignore_unknown": the same with ``ignore_unknown``,
    "original": {class or "mean": {threshold name: {precision, recall, ap}}}} — "mean" over the classes (ignoring
    NaN)."""
    ap: dict[str, dict[str, float]] = {}
    lenient: dict[str, dict[str, float]] = {}
    original: dict[str, dict[str, dict[str, float]]] = {}
    for name, c in classes.items():
        ap[name] = {threshold_name(t): detection_ap(c["pred_xy"], c["confidence"], c["true_xy"], c["known"], t).ap
                    for t in thresholds}
        lenient[name] = {threshold_name(t): detection_ap(c["pred_xy"], c["confidence"], c["true_xy"], c["known"], t,
                                                         ignore_unknown=True, present=c.get("present")).ap
                         for t in thresholds}
        if "assigned" in c:
            original[name] = {}
            for t in original_thresholds:
                o = original_ap(c["pred_xy"], c["confidence"], c["true_xy"], c["known"], c["assigned"], t,
                                c.get("present"))
                original[name][threshold_name(t)] = {"precision": o.precision, "recall": o.recall, "ap": o.ap}
    for table in (ap, lenient):
        table["mean"] = {threshold_name(t): _nanmean([table[n][threshold_name(t)] for n in classes])
                         for t in thresholds}
    if original:
        original["mean"] = {threshold_name(t): {key: _nanmean([original[n][threshold_name(t)][key] for n in original])
                                                for key in ("precision", "recall", "ap")}
                            for t in original_thresholds}
    return {"ap": ap, "ap_ignore_unknown": lenient, "original": original}
