from __future__ import annotations

import json

import numpy as np
import pytest

from pipeline.classes import UNLABELLED
from pipeline.metrics import classification_report, confusion_matrix, point_iou

# Hand example, K = 3 (the last entry is unlabelled and ignored):
#   truth 0 -> predicted 0, 0, 1    truth 1 -> 1, 2    truth 2 -> 2
TRUTH = np.array([0, 0, 0, 1, 1, 2, UNLABELLED])
PRED = np.array([0, 0, 1, 1, 2, 2, 0])
NAMES = ("a", "b", "c")


def test_confusion_matrix_counts_hand_example():
    cm = confusion_matrix(TRUTH, PRED, 3)
    assert cm.tolist() == [[2, 1, 0], [0, 1, 1], [0, 0, 1]]


def test_confusion_matrix_prediction_outside_classes_counts_nowhere():
    cm = confusion_matrix(np.array([0, 1]), np.array([UNLABELLED, 1]), 2)
    assert cm.tolist() == [[0, 0], [0, 1]]


def test_classification_report_precision_recall_f_hand_computed():
    r = classification_report(TRUTH, PRED, 3, NAMES)
    # precision = TP / predicted = [2/2, 1/2, 1/2]; recall = TP / support = [2/3, 1/2, 1/1]
    np.testing.assert_allclose(r.precision, [1.0, 0.5, 0.5])
    np.testing.assert_allclose(r.recall, [2 / 3, 0.5, 1.0])
    # F = 2PR/(P+R) x 100: 2(1)(2/3)/(5/3) = 0.8; 0.5; 2(.5)(1)/1.5 = 2/3
    np.testing.assert_allclose(r.f, [80.0, 50.0, 200 / 3])
    assert r.mean_f == pytest.approx((80 + 50 + 200 / 3) / 3)
    assert r.accuracy == pytest.approx(4 / 6)
    assert r.support.tolist() == [3, 2, 1]


def test_classification_report_mean_f_skips_absent_classes():
    r = classification_report(np.array([0, 0, 1]), np.array([0, 0, 1]), 3, NAMES)
    assert np.isnan(r.f[2])
    assert r.mean_f == pytest.approx(100.0)


def test_classification_report_never_predicted_class_scores_zero():
    r = classification_report(np.array([0, 1]), np.array([0, 0]), 2, NAMES[:2])
    assert r.f[1] == 0.0
    assert np.isnan(r.precision[1])


def test_classification_report_predicted_but_absent_class_scores_zero_outside_average():
    r = classification_report(np.array([0, 0]), np.array([0, 1]), 2, NAMES[:2])
    assert r.f[1] == 0.0
    assert r.mean_f == pytest.approx(r.f[0])


def test_classification_report_to_dict_is_json():
    d = classification_report(np.array([0, 0, 1]), np.array([0, 1, 1]), 3, NAMES).to_dict()
    back = json.loads(json.dumps(d))
    assert back["per_class"]["c"]["f"] is None
    assert back["confusion"] == [[1, 1, 0], [0, 1, 0], [0, 0, 0]]


def test_point_iou_hand_computed_over_frames():
    # frame 1: truth [0 0 1 255], pred [0 1 1 1]; frame 2: truth [1 1], pred [1 255]
    r = point_iou(
        [np.array([0, 1, 1, 1]), np.array([1, UNLABELLED])],
        [np.array([0, 0, 1, UNLABELLED]), np.array([1, 1])],
        num_classes=2,
        classes=("a", "b"),
    )
    # class 0: TP 1, FN 1 (predicted 1)            -> 1 / 2
    # class 1: TP 2, FP 1, FN 1 (predicted 255)    -> 2 / 4
    np.testing.assert_allclose(r.iou, [0.5, 0.5])
    assert r.mean_iou == pytest.approx(0.5)


def test_point_iou_absent_class_is_nan():
    r = point_iou([np.array([0, 0])], [np.array([0, 0])], num_classes=2, classes=("a", "b"))
    assert r.iou[0] == 1.0 and np.isnan(r.iou[1])
    assert json.loads(json.dumps(r.to_dict()))["iou"]["b"] is None


def test_point_iou_frame_count_mismatch_raises():
    with pytest.raises(ValueError, match="frames"):
        point_iou([np.array([0])], [], num_classes=2, classes=("a", "b"))


def test_plots_write_confusion_learning_curve_and_bars(tmp_path):
    from pipeline.plots import plot_confusion, plot_f_bars, plot_learning_curve

    cm = confusion_matrix(TRUTH, PRED, 3)
    paths = [
        plot_confusion(cm, NAMES, tmp_path / "cm.png"),
        plot_learning_curve(np.array([1.0, 0.5, 0.2]), np.array([30.0, 60.0, 70.0]), tmp_path / "lc.png", 2, 0.3),
        plot_f_bars(np.array([[50.0, 60.0, np.nan], [70.0, 80.0, 90.0]]), ["min", "max"], NAMES, tmp_path / "f.png"),
    ]
    for p in paths:
        assert p.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
