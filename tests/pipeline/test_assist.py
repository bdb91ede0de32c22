"""The review loop's head: refitted on reviews, unseen classes keep the CNN's say, held-out precision."""

from __future__ import annotations

import numpy as np

from pipeline.assist import (
    SHAPE_FEATURES,
    SampleFeatures,
    assist_probs,
    held_out_tracks,
    segment_shapes,
    segment_stats,
    track_means,
)


def _features(n_per: int = 40, seed: int = 0) -> tuple[SampleFeatures, np.ndarray]:
    """Two well separated classes (0 and 1) in the embedding; the CNN's probabilities say class 2."""
    rng = np.random.default_rng(seed)
    truth = np.repeat([0, 1], n_per)
    emb = rng.normal(size=(2 * n_per, 8)).astype(np.float32) + truth[:, None] * 4.0
    probs = np.tile(np.array([0.1, 0.1, 0.6, 0.2], np.float32), (2 * n_per, 1))
    stats = segment_stats(np.full(2 * n_per, 50), np.full(2 * n_per, 10.0), np.zeros(2 * n_per),
                          np.zeros((2 * n_per, len(SHAPE_FEATURES))))
    return SampleFeatures(emb, probs, stats), truth


def test_assist_probs_learn_the_reviewed_classes_over_the_cnn_s_guess():
    feats, truth = _features()
    labelled = np.r_[0:10, 40:50]
    probs = assist_probs(feats, labelled, truth[labelled], 4)
    assert probs.shape == (80, 5) and np.allclose(probs.sum(axis=1), 1.0, atol=1e-5)  # 4 classes + no_object
    assert (probs.argmax(axis=1) == truth).mean() > 0.95  # the CNN said class 2 everywhere


def test_assist_probs_are_the_cnn_s_until_two_classes_are_reviewed():
    feats, truth = _features()
    probs = assist_probs(feats, np.arange(5), truth[:5], 4)
    assert np.array_equal(probs[:, :4], feats.probs) and not probs[:, 4].any()
    assert assist_probs(feats, np.arange(5), truth[:5], 4, cnn_speaks=False) is None  # a CNN of other classes


def test_assist_probs_learn_classes_the_cnn_was_not_trained_on():
    feats, truth = _features()
    labels = truth + 5  # the sequence's label set has 9 classes; the CNN knows 4 others
    probs = assist_probs(feats, np.r_[0:10, 40:50], labels[np.r_[0:10, 40:50]], 9, cnn_speaks=False)
    assert probs.shape == (80, 10) and (probs.argmax(axis=1) == labels).mean() > 0.95


def test_assist_probs_learn_no_object_from_discarded_tracks():
    feats, truth = _features()
    labels = np.where(truth == 1, 4, 0)  # the second cluster was discarded
    probs = assist_probs(feats, np.arange(80), labels, 4)
    assert (probs.argmax(axis=1) == labels).mean() > 0.95


def test_track_means_average_each_track_s_samples():
    probs = np.array([[1, 0], [0, 1], [0.5, 0.5], [0.2, 0.8]], np.float32)
    mean, counts = track_means(probs, np.array([0, 0, -1, 1]), 3)
    assert np.allclose(mean[0], [0.5, 0.5]) and np.allclose(mean[1], [0.2, 0.8])
    assert counts.tolist() == [2, 1, 0]


def test_held_out_tracks_leave_whole_tracks_out():
    feats, truth = _features()
    group = np.arange(80) // 4  # 20 tracks of 4 samples, 10 per class
    held = held_out_tracks(feats, np.arange(80), truth, group, 4)
    assert held is not None and len(held.truth) == 20 and (held.samples == 4).all()
    precision, support = held.precision(0, 0.5)
    assert support >= 8 and precision > 0.9
    assert held_out_tracks(feats, np.arange(10), truth[:10], group[:10], 4) is None  # one class only


def test_held_out_tracks_learn_the_always_samples_in_every_fold_and_never_hold_them_out():
    """Reviews of class 0 only plus samples of class 1 from regions: each fold learns class 1 from
    the region samples, and only the reviewed tracks are scored."""
    feats, truth = _features()
    group = np.arange(80) // 4
    reviewed, regions = np.arange(40), np.arange(40, 80)  # class 0's tracks reviewed; class 1 from regions
    held = held_out_tracks(feats, np.r_[reviewed, 40, 41, 42, 43], np.r_[truth[reviewed], 1, 1, 1, 1],
                           np.r_[group[reviewed], 10, 10, 10, 10], 4, always=(regions[4:], truth[regions[4:]]))
    assert held is not None and len(held.truth) == 11  # 10 reviewed tracks of class 0 and one of class 1
    assert held.predicted[-1] == 1  # held out, it is still known from the regions' samples



def test_segment_shapes_tell_a_wall_a_pole_and_a_bush_apart():
    rng = np.random.default_rng(0)
    wall = np.c_[np.zeros(300), rng.uniform(0, 3, 300), rng.uniform(0, 3, 300)]  # the x = 0 plane
    pole = np.c_[rng.normal(0, 0.01, (200, 2)), rng.uniform(0, 3, 200)]
    bush = rng.normal(0, 0.5, (400, 3))
    noise = rng.uniform(-50, 50, (100, 3))  # no segment
    points = np.vstack([wall, pole, bush, noise]).astype(np.float32)
    segment = np.repeat([4, 7, 2, -1], [300, 200, 400, 100])
    intensity = np.repeat(np.float32([0.2, 0.9, 0.4, 1.0]), [300, 200, 400, 100])
    names = {n: i for i, n in enumerate(SHAPE_FEATURES)}
    s = segment_shapes(points, intensity, segment, np.array([4, 7, 2, 9]))  # 9: no point
    assert s.shape == (4, len(SHAPE_FEATURES)) and s.dtype == np.float32
    wall_, pole_, bush_, none_ = s
    assert wall_[names["planarity"]] > 0.7 and wall_[names["normal_z"]] < 0.05  # upright plane
    assert pole_[names["linearity"]] > 0.95 and abs(pole_[names["z_extent"]] - 3.0) < 0.05
    assert bush_[names["scattering"]] > 0.5 > wall_[names["scattering"]]
    assert np.allclose(s[:3, names["intensity_mean"]], [0.2, 0.9, 0.4]) and np.allclose(s[:3, names["intensity_std"]], 0)
    assert not none_.any()
