"""Anchor proposals: which samples (or tracks) of a new scene an operator should label first.

A pretrained model has scored every sample of the new scene (class probabilities, and for the
`diverse` strategy its CNN features). Each strategy picks `counts[k]` proposals for each class k
(the paper: 20 per class, 100 for unknown), each proposed with a class the operator confirms or
corrects:

- `confident`: the samples predicted k with the highest P_k (the paper's choice);
- `entropy`:   the samples predicted k whose prediction has the highest entropy (the model's
               most uncertain ones, uncertainty sampling);
- `diverse`:   greedy k-center over the CNN features of the samples predicted k, started at the
               most confident one: each next proposal is the sample farthest from those chosen,
               so the proposals cover the class's appearance rather than repeat one look;
- `track`:     one proposal per track: the track's class is the arg-max of its samples' mean
               probabilities, and per class the tracks of highest mean confidence, among tracks
               of at least `min_track_samples` samples, are proposed with a representative
               sample. Confirming one labels every sample of the track.
- `track_diverse`: as `track`, but the tracks of a class are chosen by greedy k-center over the
               tracks' mean features (a track-level `diverse`).

When fewer samples (tracks) than requested are predicted k, the rest of class k's quota is
filled with the not yet chosen samples (tracks) of highest P_k: the result always holds
min(sum(counts), available) proposals, with no sample (track) proposed twice. All of it is
pure numpy; nothing here runs the model.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from pipeline.classes import PAPER, SAMPLE_CLASSES

STRATEGIES: tuple[str, ...] = ("confident", "entropy", "diverse", "track", "track_diverse")
TRACK_STRATEGIES: frozenset[str] = frozenset({"track", "track_diverse"})
FEATURE_STRATEGIES: frozenset[str] = frozenset({"diverse", "track_diverse"})
DEFAULT_STRATEGY = "track_diverse"
DEFAULT_PER_CLASS = 20
DEFAULT_UNKNOWN = 100


@dataclass(frozen=True)
class Proposals:
    """R proposals, grouped by proposed class (class order, then rank within the class).

    index:    (R,) int64 sample index into the scored arrays (for track strategies the track's
              representative sample: its sample of highest P of the proposed class).
    proposed: (R,) int64 proposed class id.
    score:    (R,) float64 the strategy's score: P_k (confident, track: the track's mean P_k),
              entropy in nats (entropy), distance to the nearer chosen proposal in feature space
              (diverse, track_diverse; the first of each class: its P_k).
    track:    (R,) int64 track id of each proposal (0 = none given).
    strategy: the strategy's name.
    """

    index: np.ndarray
    proposed: np.ndarray
    score: np.ndarray
    track: np.ndarray
    strategy: str

    def __len__(self) -> int:
        return len(self.index)

    def per_class(self, num_classes: int) -> np.ndarray:
        """(K,) int64 proposals per proposed class."""
        return np.bincount(self.proposed, minlength=num_classes).astype(np.int64)


def class_counts(
    per_class: int = DEFAULT_PER_CLASS,
    unknown: int | None = DEFAULT_UNKNOWN,
    classes: Sequence[str] = SAMPLE_CLASSES,
    overrides: Mapping[str, int] | None = None,
    fallback: str | None = PAPER.fallback,
) -> np.ndarray:
    """(K,) int64 proposals wanted per class: `per_class` each, `unknown` for the label set's
    `fallback` class, the class of what no other class fits (None = per_class; default: the
    default set's, unknown), then `overrides` by class name."""
    counts = np.full(len(classes), per_class, np.int64)
    if fallback in classes and unknown is not None:
        counts[list(classes).index(fallback)] = unknown
    for name, n in (overrides or {}).items():
        if name not in classes:
            raise ValueError(f"unknown class {name!r}; valid: {', '.join(classes)}")
        counts[list(classes).index(name)] = n
    if (counts < 0).any():
        raise ValueError("counts must be >= 0")
    return counts


def entropy(probs: np.ndarray) -> np.ndarray:
    """(M,) float64 entropy in nats of each row of (M, K) probabilities."""
    p = np.clip(probs.astype(np.float64), 1e-12, 1.0)
    return -(p * np.log(p)).sum(axis=1)


def k_center(features: np.ndarray, count: int, first: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Greedy k-center (farthest-first traversal) over (N, D) features, started at row `first`.

    Returns (rows (n,), distance of each chosen row to the rows chosen before it (n,); the first
    gets +inf), n = min(count, N). Exact duplicates are never picked twice: once every distinct
    point is chosen the remaining picks go to the copies, still without repeating a row.
    """
    n = len(features)
    count = min(count, n)
    if count <= 0:
        return np.zeros(0, np.int64), np.zeros(0)
    x = features.astype(np.float64)
    chosen = np.zeros(count, np.int64)
    dist_at = np.zeros(count)
    chosen[0], dist_at[0] = first, np.inf
    d = np.sum((x - x[first]) ** 2, axis=1)  # (N,) squared distance to the nearest chosen row
    d[first] = -1.0
    for i in range(1, count):
        j = int(np.argmax(d))
        chosen[i], dist_at[i] = j, np.sqrt(max(d[j], 0.0))
        d = np.minimum(d, np.sum((x - x[j]) ** 2, axis=1))
        d[chosen[: i + 1]] = -1.0
    return chosen, dist_at


def _check(probs: np.ndarray, counts: np.ndarray) -> None:
    if probs.ndim != 2:
        raise ValueError(f"probs must be (M, K), got {probs.shape}")
    if counts.shape != (probs.shape[1],):
        raise ValueError(f"counts must be ({probs.shape[1]},), got {counts.shape}")


def _pick(
    probs: np.ndarray,
    counts: np.ndarray,
    rank: Callable[[int, np.ndarray, int], tuple[np.ndarray, np.ndarray]],
    available: np.ndarray,
) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Per class k: up to counts[k] rows among the available rows predicted k, ordered by
    `rank(k, rows) -> (order of rows, scores)`; then each class's shortfall from the remaining
    rows by P_k. Returns (rows per class, scores per class)."""
    k_classes = probs.shape[1]
    pred = probs.argmax(axis=1)
    taken = ~available.copy()
    rows: list[np.ndarray] = []
    scores: list[np.ndarray] = []
    for k in range(k_classes):
        cand = np.flatnonzero((pred == k) & ~taken)
        if counts[k] == 0 or len(cand) == 0:
            rows.append(np.zeros(0, np.int64))
            scores.append(np.zeros(0))
            continue
        order, sc = rank(k, cand, int(counts[k]))
        order, sc = order[: counts[k]], sc[: counts[k]]
        rows.append(cand[order].astype(np.int64))
        scores.append(np.asarray(sc, np.float64))
        taken[rows[k]] = True
    # each class's shortfall from what is left, by P_k; a row goes to the first class wanting it
    for k in range(k_classes):
        need = int(counts[k]) - len(rows[k])
        if need <= 0:
            continue
        rest = np.flatnonzero(~taken)
        if len(rest) == 0:
            break
        top = rest[np.argsort(-probs[rest, k], kind="stable")[:need]]
        rows[k] = np.concatenate([rows[k], top])
        scores[k] = np.concatenate([scores[k], probs[top, k].astype(np.float64)])
        taken[top] = True
    return rows, scores


def propose(
    probs: np.ndarray,
    strategy: str = DEFAULT_STRATEGY,
    counts: np.ndarray | Sequence[int] | None = None,
    features: np.ndarray | None = None,
    tracks: np.ndarray | None = None,
    exclude: np.ndarray | None = None,
    min_track_samples: int = 1,
) -> Proposals:
    """Propose anchors among M scored samples.

    probs:    (M, K) class probabilities of the pretrained model.
    strategy: one of STRATEGIES.
    counts:   (K,) proposals wanted per class (`class_counts` of the model's classes); None =
              DEFAULT_PER_CLASS for each (the names of the classes are not known here).
              For track strategies a count is a number of tracks.
    features: (M, D) CNN features, needed by `diverse` and `track_diverse`.
    tracks:   (M,) int64 track id per sample (> 0), needed by track strategies; samples with
              id <= 0 are left out of those.
    exclude:  (M,) bool samples never to propose (e.g. already answered); a track strategy
              leaves out every track holding an excluded sample.
    min_track_samples: track strategies prefer tracks with at least this many samples (shorter
              ones only fill a shortfall).
    """
    if strategy not in STRATEGIES:
        raise ValueError(f"unknown strategy {strategy!r}; valid: {', '.join(STRATEGIES)}")
    probs = np.asarray(probs, np.float64)
    m = len(probs)
    k_classes = probs.shape[1] if probs.ndim == 2 else 0
    counts = np.full(k_classes, DEFAULT_PER_CLASS, np.int64) if counts is None else np.asarray(counts, np.int64)
    _check(probs, counts)
    excl = np.zeros(m, bool) if exclude is None else np.asarray(exclude, bool)
    if excl.shape != (m,):
        raise ValueError(f"exclude must be ({m},), got {excl.shape}")
    if strategy in FEATURE_STRATEGIES:
        if features is None or len(features) != m:
            raise ValueError(f"strategy {strategy!r} needs features (M, D) for the {m} samples")
    if strategy in TRACK_STRATEGIES:
        if tracks is None or np.shape(tracks) != (m,):
            raise ValueError(f"strategy {strategy!r} needs a track id per sample ({m},)")
        return _propose_tracks(probs, strategy, counts, features, np.asarray(tracks, np.int64), excl, min_track_samples)

    conf = probs.max(axis=1)
    ent = entropy(probs)

    def rank_confident(k: int, cand: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
        order = np.argsort(-probs[cand, k], kind="stable")
        return order, probs[cand[order], k]

    def rank_entropy(k: int, cand: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
        order = np.argsort(-ent[cand], kind="stable")
        return order, ent[cand[order]]

    def rank_diverse(k: int, cand: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
        assert features is not None
        first = int(np.argmax(conf[cand]))
        order, dist = k_center(np.asarray(features)[cand], n, first)
        dist = dist.copy()
        dist[0] = probs[cand[first], k]
        return order, dist

    rank = {"confident": rank_confident, "entropy": rank_entropy, "diverse": rank_diverse}[strategy]
    rows, scores = _pick(probs, counts, rank, ~excl)
    proposed = [np.full(len(r), k, np.int64) for k, r in enumerate(rows)]
    index = np.concatenate(rows) if rows else np.zeros(0, np.int64)
    track_ids = np.zeros(len(index), np.int64) if tracks is None else np.asarray(tracks, np.int64)[index]
    return Proposals(index, np.concatenate(proposed), np.concatenate(scores), track_ids, strategy)


def track_table(probs: np.ndarray, tracks: np.ndarray, features: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """Per-track aggregates of the samples with track id > 0.

    Returns ids (T,), first (M,) track row of each sample (-1 = none), size (T,) samples,
    mean_probs (T, K), and mean_features (T, D) when features are given.
    """
    has = tracks > 0
    ids, inv = np.unique(tracks[has], return_inverse=True)
    row = np.full(len(tracks), -1, np.int64)
    row[has] = inv
    size = np.bincount(inv, minlength=len(ids)).astype(np.int64)
    mean_probs = np.zeros((len(ids), probs.shape[1]))
    np.add.at(mean_probs, inv, probs[has])
    mean_probs /= np.maximum(size, 1)[:, None]
    out = {"ids": ids, "row": row, "size": size, "mean_probs": mean_probs}
    if features is not None:
        f = np.asarray(features, np.float64)
        mean_f = np.zeros((len(ids), f.shape[1]))
        np.add.at(mean_f, inv, f[has])
        out["mean_features"] = mean_f / np.maximum(size, 1)[:, None]
    return out


def _propose_tracks(
    probs: np.ndarray,
    strategy: str,
    counts: np.ndarray,
    features: np.ndarray | None,
    tracks: np.ndarray,
    excl: np.ndarray,
    min_track_samples: int,
) -> Proposals:
    tab = track_table(probs, tracks, features if strategy == "track_diverse" else None)
    n_tracks = len(tab["ids"])
    tprobs = tab["mean_probs"]  # (T, K)
    blocked = np.zeros(n_tracks, bool)
    if excl.any():
        rows = tab["row"][excl]
        blocked[rows[rows >= 0]] = True
    short = tab["size"] < min_track_samples
    tconf = tprobs.max(axis=1) if n_tracks else np.zeros(0)

    def rank_confident(k: int, cand: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
        order = np.argsort(-tprobs[cand, k], kind="stable")
        return order, tprobs[cand[order], k]

    def rank_diverse(k: int, cand: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
        first = int(np.argmax(tconf[cand]))
        order, dist = k_center(tab["mean_features"][cand], n, first)
        dist = dist.copy()
        dist[0] = tprobs[cand[first], k]
        return order, dist

    rank = rank_confident if strategy == "track" else rank_diverse
    # long enough tracks first; short ones only fill what the long ones leave
    rows_long, sc_long = _pick(tprobs, counts, rank, ~blocked & ~short)
    taken = blocked | ~short
    for r in rows_long:
        taken[r] = True
    rest_counts = counts - np.array([len(r) for r in rows_long])
    if rest_counts.any() and (~taken).any():
        rows_short, sc_short = _pick(tprobs, rest_counts, rank_confident, ~taken)
        rows_long = [np.concatenate([a, b]) for a, b in zip(rows_long, rows_short, strict=True)]
        sc_long = [np.concatenate([a, b]) for a, b in zip(sc_long, sc_short, strict=True)]
    trows = np.concatenate(rows_long) if rows_long else np.zeros(0, np.int64)
    proposed = np.concatenate([np.full(len(r), k, np.int64) for k, r in enumerate(rows_long)])
    # representative sample of each proposed track: its sample of highest P of the proposed class
    rep = np.zeros(len(trows), np.int64)
    if len(trows):
        sample_row = tab["row"]
        has = np.flatnonzero(sample_row >= 0)
        pos = np.full(n_tracks, -1, np.int64)
        pos[trows] = np.arange(len(trows))
        sel = has[pos[sample_row[has]] >= 0]  # samples of proposed tracks
        p = pos[sample_row[sel]]  # proposal position of each
        val = probs[sel, proposed[p]]
        order = np.lexsort((-val, p))  # by proposal, best sample first
        first = np.ones(len(order), bool)
        first[1:] = p[order][1:] != p[order][:-1]
        rep[p[order][first]] = sel[order][first]
    return Proposals(rep, proposed, np.concatenate(sc_long), tab["ids"][trows], strategy)
