from __future__ import annotations

import numpy as np
import pytest

from pipeline.anchors import (
    STRATEGIES,
    TRACK_STRATEGIES,
    class_counts,
    entropy,
    k_center,
    propose,
    track_table,
)

K = 7


def scored(m: int, seed: int, skew: float = 0.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(probs (M, K), features (M, 8), tracks (M,)): random scores; `skew` makes class 0 rare
    among the predictions; tracks of 1..9 samples."""
    rng = np.random.default_rng(seed)
    logits = rng.normal(size=(m, K)) * 2
    logits[:, 0] -= skew
    p = np.exp(logits)
    p /= p.sum(1, keepdims=True)
    feats = rng.normal(size=(m, 8))
    lengths = rng.integers(1, 10, m)
    tracks = np.repeat(np.arange(1, m + 1), lengths)[:m]
    return p, feats, tracks


def test_class_counts_defaults_to_paper():
    c = class_counts()
    assert c.tolist() == [20, 20, 20, 20, 20, 20, 100]
    assert class_counts(5, None).tolist() == [5] * 7
    assert class_counts(3, 10, overrides={"car": 1}).tolist() == [3, 1, 3, 3, 3, 3, 10]
    with pytest.raises(ValueError, match="unknown class"):
        class_counts(overrides={"lorry": 2})


@pytest.mark.parametrize("strategy", STRATEGIES)
@pytest.mark.parametrize("skew", [0.0, 6.0])
def test_each_strategy_returns_requested_count_without_duplicates(strategy: str, skew: float):
    probs, feats, tracks = scored(6000, seed=1, skew=skew)  # ~1200 tracks, ~170 predicted per class
    counts = class_counts(20, 100)
    out = propose(probs, strategy, counts, features=feats, tracks=tracks)
    assert len(out) == counts.sum()
    assert out.per_class(K).tolist() == counts.tolist()  # even class 0, rarely predicted with skew
    assert len(np.unique(out.index)) == len(out)  # no sample twice
    assert np.isfinite(out.score).all()
    if strategy in TRACK_STRATEGIES:
        assert len(np.unique(out.track)) == len(out)  # no track twice
        assert (tracks[out.index] == out.track).all()  # the representative belongs to its track
    if skew == 0.0 and strategy != "entropy":
        # with classes evenly predicted every proposal comes from its own predicted class
        if strategy in TRACK_STRATEGIES:
            tab = track_table(probs, tracks)
            row = np.searchsorted(tab["ids"], out.track)
            assert (tab["mean_probs"][row].argmax(1) == out.proposed).all()
        else:
            assert (probs[out.index].argmax(1) == out.proposed).all()


@pytest.mark.parametrize("strategy", STRATEGIES)
def test_fewer_candidates_than_requested_returns_all_once(strategy: str):
    probs, feats, tracks = scored(50, seed=2)
    out = propose(probs, strategy, class_counts(20, 100), features=feats, tracks=tracks)
    available = len(np.unique(tracks)) if strategy in TRACK_STRATEGIES else 50
    assert len(out) == available
    assert len(np.unique(out.index)) == len(out)


@pytest.mark.parametrize("strategy", STRATEGIES)
def test_excluded_samples_are_never_proposed(strategy: str):
    probs, feats, tracks = scored(800, seed=3)
    exclude = np.zeros(800, bool)
    exclude[::3] = True
    out = propose(probs, strategy, class_counts(5, 10), features=feats, tracks=tracks, exclude=exclude)
    free_tracks = len(np.setdiff1d(tracks, tracks[exclude]))
    assert len(out) == (min(40, free_tracks) if strategy in TRACK_STRATEGIES else 40)
    assert not exclude[out.index].any()
    if strategy in TRACK_STRATEGIES:
        assert not np.isin(out.track, tracks[exclude]).any()  # no track holding an excluded sample


def test_confident_and_entropy_rank_as_named():
    probs, _, _ = scored(2000, seed=4)
    pred = probs.argmax(1)
    conf = propose(probs, "confident", np.full(K, 5))
    ent = propose(probs, "entropy", np.full(K, 5))
    h = entropy(probs)
    for k in range(K):
        cand = np.flatnonzero(pred == k)
        best = np.sort(probs[cand, k])[::-1][:5]
        assert np.allclose(np.sort(probs[conf.index[conf.proposed == k], k])[::-1], best)
        assert np.allclose(np.sort(h[ent.index[ent.proposed == k]])[::-1], np.sort(h[cand])[::-1][:5])


def test_k_center_covers_clusters_and_never_repeats():
    rng = np.random.default_rng(5)
    centres = np.array([[0, 0], [100, 0], [0, 100], [100, 100]], float)
    x = np.concatenate([c + rng.normal(size=(50, 2)) for c in centres])
    rows, dist = k_center(x, 4, first=0)
    assert sorted(r // 50 for r in rows) == [0, 1, 2, 3]  # one per cluster
    assert dist[0] == np.inf and (dist[1:] > 50).all()
    dup = np.zeros((10, 3))  # all identical: still 10 distinct rows
    rows, _ = k_center(dup, 10)
    assert sorted(rows.tolist()) == list(range(10))


def test_diverse_spreads_over_feature_clusters_where_confident_does_not():
    # class 0 samples in two feature clusters; the most confident all lie in cluster A
    m = 200
    probs = np.full((m, K), 0.01)
    probs[:, 0] = np.linspace(0.99, 0.5, m)
    probs /= probs.sum(1, keepdims=True)
    feats = np.zeros((m, 2))
    feats[100:, 0] = 50.0  # the less confident half is cluster B
    counts = np.zeros(K, np.int64)
    counts[0] = 6
    conf = propose(probs, "confident", counts, features=feats)
    div = propose(probs, "diverse", counts, features=feats)
    assert (conf.index < 100).all()
    assert (div.index >= 100).any() and (div.index < 100).any()


def test_track_strategy_uses_track_mean_and_min_length():
    # tracks 1, 2 (3 samples each, class 1), track 3 (1 sample, class 1, most confident)
    probs = np.full((7, K), 0.02)
    probs[:, 1] = [0.8, 0.7, 0.9, 0.6, 0.6, 0.6, 0.99]
    probs /= probs.sum(1, keepdims=True)
    tracks = np.array([1, 1, 1, 2, 2, 2, 3])
    counts = np.zeros(K, np.int64)
    counts[1] = 2
    out = propose(probs, "track", counts, tracks=tracks, min_track_samples=2)
    assert out.track.tolist() == [1, 2]  # track 3 is too short while longer ones remain
    assert out.index.tolist()[0] == 2  # track 1's representative: its most confident sample
    counts[1] = 3
    out = propose(probs, "track", counts, tracks=tracks, min_track_samples=2)
    assert sorted(out.track.tolist()) == [1, 2, 3]  # the short one fills the shortfall


def test_bad_inputs_are_refused():
    probs, feats, tracks = scored(20, seed=6)
    with pytest.raises(ValueError, match="unknown strategy"):
        propose(probs, "random")
    with pytest.raises(ValueError, match="needs features"):
        propose(probs, "diverse")
    with pytest.raises(ValueError, match="track id"):
        propose(probs, "track")
    with pytest.raises(ValueError, match="counts"):
        propose(probs, "confident", [1, 2])
