"""Inference, the algorithm: class per point, causal track smoothing, point accuracy."""

from __future__ import annotations

import numpy as np

from pipeline.classes import GROUND, UNLABELLED
from pipeline.predict import TrackSmoother, point_accuracy, predict_frame_classes
from tests.pipeline.frame_factory import frame


def test_predict_frame_classes_spread_segment_classes_to_points_and_ground():
    fr = frame(0, [0, 0, 1, -1, -1, 2], [4, 0, 5], [np.nan] * 3, ground=[0, 0, 0, 1, 0, 0])
    probs = np.array([[0.1, 0.7, 0.2], [0.6, 0.3, 0.1]], np.float32)  # segments 0 and 2 have samples
    pred = predict_frame_classes(fr, probs)
    assert pred.point_class.tolist() == [1, 1, UNLABELLED, GROUND, UNLABELLED, 0]
    np.testing.assert_allclose(pred.confidence, [0.7, 0.7, 0, 0, 0, 0.6])
    assert pred.segment.tolist() == [0, 2] and pred.track.tolist() == [4, 5]


def test_predict_track_smoother_averages_each_track_causally():
    smooth = TrackSmoother()
    a = smooth(np.array([3, 0]), np.array([[1.0, 0.0], [0.2, 0.8]]))
    b = smooth(np.array([3]), np.array([[0.0, 1.0]]))
    assert a.tolist() == [[1.0, 0.0], [0.2, 0.8]]  # track 0 is none: never averaged
    assert b.tolist() == [[0.5, 0.5]]


def test_predict_point_accuracy_over_labelled_and_object_points():
    pred = [np.array([1, 2, GROUND, 4], np.uint8)]
    truth = [np.array([1, 3, GROUND, UNLABELLED], np.uint8)]
    assert point_accuracy(pred, truth) == {"point_accuracy": round(2 / 3, 4), "object_point_accuracy": 0.5}
