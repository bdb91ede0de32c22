"""The model in the review loop: a classifier of one sequence's samples, refitted on the
operator's reviews as they come in, over what the shipped (or the sequence's own) CNN sees.

Each sample is described by the CNN's embedding and class probabilities and by its segment's
size, range, height and shape (`segment_shapes`: how linear, planar or scattered its points
are, how upright, how tall and wide, and their intensity); a random forest fitted on the samples of reviewed tracks classifies every
other sample into the sequence's own classes, whatever classes the CNN was trained on (its view
is only the forest's input). Until the reviews show two classes the CNN's own probabilities
stand when it was trained on the sequence's classes, and nothing is predicted otherwise; from
then on the forest alone decides. Measured on the shared real clips (docs/effort.md): the forest labelled
about as many points right as the CNN fine-tuned on the same reviews (0.757 against 0.760 on the
mean of the three clips after 50 oracle reviews) and refits about a hundred times faster, which
keeps a retrain within the minute a reviewer waits; letting the CNN keep its probability for
classes no review has shown, or keeping the CNN until it predicts the reviewed tracks worse than
the forest, each lost points on some clips.

Tracks the operator discarded teach one more class, `NO_OBJECT` (pieces of ground, noise: what
operators throw away); a track the head calls so is left out of bulk accepts and of the
classes its points take.

`held_out_tracks` estimates, from the reviewed tracks themselves (each fold leaves whole tracks
out), how often a track predicted as a class with a given confidence is right: the figure a bulk
accept's preview shows.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pipeline.errors import DataError

NO_OBJECT = "no_object"  # the head's extra class: tracks operators discard
N_TREES = 200
MIN_LEAF = 2
FOLDS = 5


# what `segment_shapes` gives per segment. The shape features are new beside the CNN's view: the
# CNN sees a rendered neighbourhood, the forest gets a fence's flatness and a bush's scatter as
# numbers. Measured (docs/effort.md), the forest labels more points right with them on each
# shared clip (three seeds each).
SHAPE_FEATURES = ("linearity", "planarity", "scattering", "normal_z", "z_extent", "xy_major", "xy_minor",
                  "intensity_mean", "intensity_std")
STATS = 3 + len(SHAPE_FEATURES)


@dataclass(frozen=True)
class SampleFeatures:
    """What the head reads of N samples.

    embedding: (N, D) float32 the CNN's features; probs: (N, K) float32 its class probabilities;
    stats: (N, STATS) float32 per segment (`segment_stats`).
    """

    embedding: np.ndarray
    probs: np.ndarray
    stats: np.ndarray

    def __post_init__(self) -> None:
        n = len(self.probs)
        assert self.embedding.shape[0] == n and self.stats.shape == (n, STATS), (self.embedding.shape, self.stats.shape)

    def matrix(self) -> np.ndarray:
        """(N, D + K + STATS) float32 the forest's input."""
        return np.hstack([self.embedding, self.probs, self.stats]).astype(np.float32)


def segment_stats(n_points: np.ndarray, rng: np.ndarray, height: np.ndarray, shapes: np.ndarray) -> np.ndarray:
    """(N, STATS) float32 `SampleFeatures.stats`: log(points), range (m), centroid height in the
    lidar frame (m), then the (N, len(SHAPE_FEATURES)) `segment_shapes`."""
    size = np.stack([np.log(np.maximum(n_points, 1)), rng, height], axis=1)
    return np.hstack([size, shapes]).astype(np.float32)


def segment_shapes(points: np.ndarray, intensity: np.ndarray, segment: np.ndarray, ids: np.ndarray) -> np.ndarray:
    """(len(ids), len(SHAPE_FEATURES)) float32 of the segments `ids` of one frame, from its (N, 3)
    lidar points, (N,) intensity and (N,) segment id per point (-1 = none): the eigenvalues
    l1 >= l2 >= l3 of each segment's covariance as linearity (l1 - l2) / l1, planarity
    (l2 - l3) / l1 and scattering l3 / l1, |z| of its normal (the smallest eigenvector), its
    height extent and horizontal spreads (m, the square roots of its x-y covariance's
    eigenvalues), and its intensity's mean and spread. Zeros for an id without points."""
    ids = np.asarray(ids, np.int64)
    k = len(ids)
    out = np.zeros((k, len(SHAPE_FEATURES)), np.float32)
    seg = np.asarray(segment, np.int64)
    if k == 0 or len(seg) == 0:
        return out
    row_of = np.full(max(int(seg.max()), int(ids.max())) + 2, -1, np.int64)  # last slot: segment -1
    row_of[ids] = np.arange(k)
    row = row_of[seg]
    m = row >= 0
    r, p, it = row[m], np.asarray(points, np.float64)[m], np.asarray(intensity, np.float64)[m]
    n = np.bincount(r, minlength=k).astype(np.float64)
    has, nn = n > 0, np.maximum(n, 1.0)
    mean = np.stack([np.bincount(r, p[:, j], k) for j in range(3)], axis=1) / nn[:, None]
    d = p - mean[r]
    cov = np.empty((k, 3, 3))
    for a in range(3):
        for b in range(a, 3):
            cov[:, a, b] = cov[:, b, a] = np.bincount(r, d[:, a] * d[:, b], k) / nn
    ev, vec = np.linalg.eigh(cov + 1e-9 * np.eye(3))  # ascending
    l3, l2, l1 = (np.maximum(ev[:, i], 1e-12) for i in range(3))
    z_lo, z_hi = np.full(k, np.inf), np.full(k, -np.inf)
    np.minimum.at(z_lo, r, p[:, 2])
    np.maximum.at(z_hi, r, p[:, 2])
    xy = np.sqrt(np.maximum(np.linalg.eigvalsh(cov[:, :2, :2]), 0.0))  # ascending
    i_mean = np.bincount(r, it, k) / nn
    i_std = np.sqrt(np.bincount(r, (it - i_mean[r]) ** 2, k) / nn)
    cols = ((l1 - l2) / l1, (l2 - l3) / l1, l3 / l1, np.abs(vec[:, 2, 0]), z_hi - z_lo, xy[:, 1], xy[:, 0], i_mean, i_std)
    out[has] = np.stack(cols, axis=1)[has]
    return out


def _fit(x: np.ndarray, y: np.ndarray, seed: int):
    from sklearn.ensemble import RandomForestClassifier

    return RandomForestClassifier(N_TREES, min_samples_leaf=MIN_LEAF, n_jobs=-1, random_state=seed).fit(x, y)


def _full(forest: object, x: np.ndarray, k: int) -> np.ndarray:
    """(N, K) the forest's probabilities over all K classes (0 for those it was not fitted on)."""
    out = np.zeros((len(x), k), np.float32)
    out[:, forest.classes_] = forest.predict_proba(x)  # type: ignore[attr-defined]
    return out


def _cnn(features: SampleFeatures, n: int, speaks: bool) -> np.ndarray:
    """(N, n) the CNN's probabilities, 0 for the head's classes beyond the CNN's; all 0 when the
    CNN was not trained on the head's classes (`speaks` False)."""
    out = np.zeros((len(features.probs), n), np.float32)
    if speaks:
        out[:, : features.probs.shape[1]] = features.probs
    return out


def assist_probs(features: SampleFeatures, labelled: np.ndarray, labels: np.ndarray, k: int, cnn_speaks: bool = True,
                 seed: int = 0) -> np.ndarray | None:
    """(N, k + 1) float32 probabilities of every sample over the sequence's k classes and
    NO_OBJECT (class k): the forest fitted on `labelled` (indices) with `labels` (0..k) once the
    reviews show two classes; before, the CNN's own when it was trained on those k classes
    (`cnn_speaks`), else None (nothing to predict with)."""
    labelled, labels = np.asarray(labelled, np.int64), np.asarray(labels, np.int64)
    if labelled.shape != labels.shape:
        raise DataError(None, f"labelled {labelled.shape} and labels {labels.shape} differ")
    if len(np.unique(labels)) < 2:
        return _cnn(features, k + 1, True) if cnn_speaks else None
    x = features.matrix()
    return _full(_fit(x[labelled], labels, seed), x, k + 1)


def track_means(probs: np.ndarray, group: np.ndarray, n_groups: int) -> tuple[np.ndarray, np.ndarray]:
    """Per group (track) the mean (G, K) of its samples' probabilities and its (G,) sample count;
    samples with group < 0 belong to none."""
    k = probs.shape[1]
    sums = np.zeros((n_groups, k), np.float64)
    counts = np.zeros(n_groups, np.int64)
    ok = group >= 0
    np.add.at(sums, group[ok], probs[ok])
    np.add.at(counts, group[ok], 1)
    return sums / np.maximum(counts, 1)[:, None], counts


@dataclass(frozen=True)
class HeldOutTracks:
    """The reviewed tracks' own predictions with their track left out of the fit:
    truth, predicted class and confidence, each (T,), and each track's samples (T,)."""

    truth: np.ndarray
    predicted: np.ndarray
    confidence: np.ndarray
    samples: np.ndarray

    def precision(self, class_index: int, min_confidence: float) -> tuple[float | None, int]:
        """(share right, support) of the held-out tracks predicted `class_index` at or above
        `min_confidence` (None when there is none)."""
        sel = (self.predicted == class_index) & (self.confidence >= min_confidence)
        n = int(sel.sum())
        return (float((self.truth[sel] == class_index).mean()) if n else None), n


def held_out_tracks(features: SampleFeatures, labelled: np.ndarray, labels: np.ndarray, group: np.ndarray, k: int,
                    cnn_speaks: bool = True, seed: int = 0,
                    always: tuple[np.ndarray, np.ndarray] | None = None) -> HeldOutTracks | None:
    """Cross-validated track predictions of the reviewed tracks (`group`: the track of each
    labelled sample) over k classes and NO_OBJECT, as `assist_probs`: FOLDS folds of whole
    tracks; `always` (indices, labels): samples every fold also learns from and none holds out.
    None with fewer than two classes or tracks than folds."""
    labelled, labels, group = (np.asarray(a, np.int64) for a in (labelled, labels, group))
    tracks, inverse = np.unique(group, return_inverse=True)
    if len(np.unique(labels)) < 2 or len(tracks) < FOLDS:
        return None
    fold = np.random.default_rng(seed).permutation(len(tracks)) % FOLDS
    always_at, always_y = (np.zeros(0, np.int64),) * 2 if always is None else (np.asarray(a, np.int64) for a in always)
    x_all = features.matrix()
    x, x_always = x_all[labelled], x_all[always_at]
    n = k + 1
    base = _cnn(features, n, cnn_speaks)[labelled]
    probs = np.zeros_like(base)
    for f in range(FOLDS):
        out = fold[inverse] == f
        y = np.concatenate([labels[~out], always_y])
        if len(np.unique(y)) < 2:
            probs[out] = base[out]
            continue
        probs[out] = _full(_fit(np.concatenate([x[~out], x_always]), y, seed), x[out], n)
    mean, counts = track_means(probs, inverse, len(tracks))
    truth = np.zeros(len(tracks), np.int64)
    truth[inverse] = labels
    return HeldOutTracks(truth, mean.argmax(axis=1), mean.max(axis=1), counts)

