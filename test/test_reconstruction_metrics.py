"""The localization and reconstruction metrics against hand-computed cases."""
import math

import numpy as np
import pytest

from dynenv_ros.learning.pretrain import reconstruction_metrics as rm


def _one_step(pred, conf, truth, known):
    """Arrays for one robot-step: pred (S, 2), conf (S,), truth (M, 2), known (M,)."""
    return (np.asarray(pred, float)[None], np.asarray(conf, float)[None], np.asarray(truth, float)[None],
            np.asarray(known, bool)[None])


def test_threshold_names():
    assert [rm.threshold_name(t) for t in rm.THRESHOLDS] == ["25cm", "50cm", "1m"]
    assert [rm.threshold_name(t) for t in rm.ORIGINAL_RECON_THRESHOLDS] == ["52cm", "1.04m", "2.08m"]


def test_localization_fractions_hand_case():
    true = np.zeros((4, 2))
    pred = np.array([[0.1, 0.0], [0.0, -0.3], [0.7, 0.0], [0.9, 1.2]])      # errors 0.1, 0.3, 0.7, 1.5
    assert rm.localization_fractions(pred, true) == {"25cm": 0.25, "50cm": 0.5, "1m": 0.75}
    masked = rm.localization_fractions(pred, true, mask=np.array([True, True, False, False]))
    assert masked == {"25cm": 0.5, "50cm": 1.0, "1m": 1.0}
    assert rm.localization_fractions(pred.reshape(2, 2, 2), true.reshape(2, 2, 2))["50cm"] == 0.5


def test_ap_three_predictions_two_truths_with_a_duplicate():
    # truths A (0, 0) and B (2, 0), both known. Ranked: a 0.9 hits A (TP); b 0.8 is also near A only, which a
    # already took: a duplicate, FP; c 0.7 hits B (TP).
    pred, conf, truth, known = _one_step([[0.1, 0.0], [0.0, 0.1], [2.2, 0.0]], [0.9, 0.8, 0.7],
                                         [[0.0, 0.0], [2.0, 0.0]], [True, True])
    hits = rm.match_detections(pred, conf, truth, known, 0.5)
    assert hits.tolist() == [[True, False, True]]
    result = rm.detection_ap(pred, conf, truth, known, 0.5)
    # precision 1/1, 1/2, 2/3 at recall 1/2, 1/2, 2/2; envelope 1, 2/3, 2/3
    np.testing.assert_allclose(result.precision, [1.0, 0.5, 2 / 3])
    np.testing.assert_allclose(result.recall, [0.5, 0.5, 1.0])
    expected = 0.5 * 1.0 + 0.0 * (2 / 3) + 0.5 * (2 / 3)
    assert result.ap == pytest.approx(expected)            # 0.8333
    assert (result.true_positives, result.detections, result.objects) == (2, 3, 2)
    # at 0.05 m nothing is within reach: AP 0
    assert rm.detection_ap(pred, conf, truth, known, 0.05).ap == 0.0


def test_ap_ranks_over_the_whole_set_and_unknown_objects_do_not_count():
    # step 0: a known object at (0, 0), a slot on it with confidence 0.6 (TP);
    # step 1: a known object at (3, 3) and an UNKNOWN one at (1, 1); its slot sits on the unknown one with
    # confidence 0.9: a false positive (the robot cannot know it), and the known object is missed.
    pred = np.array([[[0.0, 0.0]], [[1.0, 1.0]]])
    conf = np.array([[0.6], [0.9]])
    truth = np.array([[[0.0, 0.0], [9.0, 9.0]], [[3.0, 3.0], [1.0, 1.0]]])
    known = np.array([[True, False], [True, False]])
    result = rm.detection_ap(pred, conf, truth, known, 0.5)
    # ranked: 0.9 FP, 0.6 TP → precision 0, 1/2; recall 0, 1/2 (2 known objects); envelope 1/2, 1/2
    np.testing.assert_allclose(result.precision, [0.0, 0.5])
    np.testing.assert_allclose(result.recall, [0.0, 0.5])
    assert result.ap == pytest.approx(0.0 * 0.5 + 0.5 * 0.5)
    # COCO-style "ignore": the slot on the unknown object leaves the ranking; 0.6 TP → P 1 at R 1/2
    lenient = rm.detection_ap(pred, conf, truth, known, 0.5, ignore_unknown=True)
    np.testing.assert_allclose(lenient.precision, [1.0])
    assert lenient.ap == pytest.approx(0.5)
    # … unless the unknown row is no real object (padding): then it stays a false positive
    present = np.array([[True, True], [True, False]])
    assert rm.detection_ap(pred, conf, truth, known, 0.5, ignore_unknown=True, present=present).ap \
        == pytest.approx(0.25)


def test_perfect_predictor_gives_one_and_nothing_confident_gives_zero():
    rng = np.random.default_rng(0)
    truth = rng.uniform(-4, 4, size=(50, 3, 2))
    known = rng.random((50, 3)) < 0.6
    # a slot exactly on every known object, confident; the other slots elsewhere and less confident
    pred = np.where(known[..., None], truth, truth + 3.0)
    conf = np.where(known, 0.9, 0.1)
    assert rm.detection_ap(pred, conf, truth, known, 0.25).ap == pytest.approx(1.0)
    # the same ranking without anything above 0.95 confidence: no detection left, AP 0
    assert rm.detection_ap(pred, conf, truth, known, 0.25, min_confidence=0.95).ap == 0.0
    # every slot far from every object: AP 0
    assert rm.detection_ap(truth + 10.0, conf, truth, known, 0.25).ap == 0.0
    # no known object: undefined
    assert math.isnan(rm.detection_ap(pred, conf, truth, np.zeros_like(known), 0.25).ap)


def test_ties_are_one_operating_point():
    # two slots with the same confidence, one TP one FP, in either slot order: one point (P 1/2, R 1)
    for order in ([[0.0, 0.0], [5.0, 5.0]], [[5.0, 5.0], [0.0, 0.0]]):
        pred, conf, truth, known = _one_step(order, [0.7, 0.7], [[0.0, 0.0]], [True])
        result = rm.detection_ap(pred, conf, truth, known, 0.5)
        assert result.ap == pytest.approx(0.5)
        np.testing.assert_allclose(result.precision, [0.5])


def test_original_ap_hand_case():
    # two robot-steps, two slots, two objects per step.
    pred = np.array([[[3.1, 0.0], [0.2, 0.0]],          # step 0: slot 0 on the UNKNOWN object, slot 1 on the known
                     [[1.1, 1.0], [-2.0, -2.0]]])      # step 1: slot 0 on the known object, slot 1 on nothing
    conf = np.array([[0.9, 0.4], [0.8, 0.7]])
    truth = np.array([[[0.0, 0.0], [3.0, 0.0]], [[1.0, 1.0], [6.0, 6.0]]])
    known = np.array([[True, False], [True, False]])
    assigned = np.array([[1, 0], [0, 1]])
    o = rm.original_ap(pred, conf, truth, known, assigned, 0.52)
    # confident slots: (0,0), (1,0), (1,1) = 3; near ANY object: (0,0) (the unknown one counts), (1,0) = 2
    # known objects 2; step 0's sits at its slot 1 but not confidently; step 1's at slot 0, confident: 1
    assert (o.confident, o.confident_near, o.objects, o.recalled) == (3, 2, 2, 1)
    assert o.precision == pytest.approx(2 / 3)
    assert o.recall == pytest.approx(1 / 2)
    assert o.ap == pytest.approx((2 / 3 + 1 / 2) / 2)
    # the assigned slot is what counts for recall: assign step 1's object to the empty slot and it is missed
    o2 = rm.original_ap(pred, conf, truth, known, np.array([[1, 0], [1, 0]]), 0.52)
    assert o2.recall == 0.0
    # a real AP on the same case: ranked 0.9 FP (unknown object), 0.8 TP, 0.7 FP, 0.4 TP (2 known objects)
    real = rm.detection_ap(pred, conf, truth, known, 0.52)
    np.testing.assert_allclose(real.precision, [0.0, 0.5, 1 / 3, 0.5])
    assert real.ap == pytest.approx(0.5 * 0.5 + 0.5 * 0.5)


def test_reconstruction_report_means_over_classes():
    pred, conf, truth, known = _one_step([[0.1, 0.0], [0.0, 0.1], [2.2, 0.0]], [0.9, 0.8, 0.7],
                                         [[0.0, 0.0], [2.0, 0.0]], [True, True])
    classes = {"robots": {"pred_xy": pred, "confidence": conf, "true_xy": truth, "known": known,
                          "assigned": np.array([[0, 2]])},
               "ball": {"pred_xy": np.array([[[0.0, 0.0]]]), "confidence": np.array([[0.9]]),
                        "true_xy": np.array([[[0.0, 0.0]]]), "known": np.array([[True]]),
                        "assigned": np.zeros((1, 1), int)}}
    report = rm.reconstruction_report(classes)
    assert report["ap"]["ball"]["50cm"] == pytest.approx(1.0)
    assert report["ap"]["robots"]["50cm"] == pytest.approx(5 / 6)
    assert report["ap"]["mean"]["50cm"] == pytest.approx((1.0 + 5 / 6) / 2)
    assert report["ap_ignore_unknown"]["mean"]["50cm"] == pytest.approx((1.0 + 5 / 6) / 2)   # nothing unknown
    # original at 52 cm: robots: 3 confident, all near an object → P 1; both recalled → R 1
    assert report["original"]["robots"]["52cm"]["ap"] == pytest.approx(1.0)
    assert set(report["original"]["mean"]) == {"52cm", "1.04m", "2.08m"}
