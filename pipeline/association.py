"""Frame-to-frame association of segments into tracks.

For frame t, every point of a valid segment is moved into frame t-1 with the ego-motion
(`T_prev_curr = inv(T_world_prev) @ T_world_curr`) and projected into t-1's range image. A point
votes for the t-1 segment owning that pixel when its range agrees with the pixel's range. The link
score of (a, b) is votes(a -> b) / max(n_a, n_b). Tracks that move (constant-velocity
state) are also matched by predicted centroid when the overlap is weak, within a gate that grows
with their speed. Pairs are solved one-to-one with the Hungarian method. A segment left over that
lands on nothing when moved as a static object gets a first link by a motion hypothesis: each
unmatched t-1 segment within `max_speed` x dt is tried as where it was, and the hypothesis is
kept only when the segment's points, moved back by it, land on that segment (a car on a highway
moves 2-3 m a frame, further than its own length from where a static object would be).
Precision beats recall (a wrong link teaches the model a wrong equality), so a segment whose votes
split between two t-1 segments (a merge) or whose point count jumps is left unlinked.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field, replace
from functools import partial

import numpy as np
from numba import njit
from scipy.optimize import linear_sum_assignment
from scipy.spatial.distance import cdist

from pipeline.config import AssociationConfig
from pipeline.sensors import SensorModel
from pipeline.votes import moving_votes, points_by_segment, vote_matrix

# First links by a motion hypothesis (`_first_links`), chosen on the three labelled real clips
# together (docs/perception.md): segments of at least this many points (smaller pieces of foliage
# and fences reshuffle between frames and found wrong links 2-4 m apart), that a static object
# explains under FIRST_LINK_STATIC of, whose points land on their match for at least
# FIRST_LINK_MIN_SHARE when moved back, and whose best hypothesis no other one reaches within
# FIRST_LINK_UNIQUE of its score (a row of posts or shrubs fits many).
FIRST_LINK_MIN_POINTS = 30
FIRST_LINK_MIN_SHARE = 0.3
FIRST_LINK_STATIC = 0.3
FIRST_LINK_UNIQUE = 0.5


@dataclass(frozen=True)
class AssociationFrame:
    """What association keeps of a frame.

    seg_pixel: (H, W) int32 valid-segment id per pixel, -1 = none; range: (H, W) float32 pixel range.
    n_points: (S,) int32; centroid_world: (S, 3) float64; valid: (S,) bool.
    T_world_lidar: (4, 4) float64 or None; time: seconds.
    """

    seg_pixel: np.ndarray
    range: np.ndarray
    n_points: np.ndarray
    centroid_world: np.ndarray
    valid: np.ndarray
    T_world_lidar: np.ndarray | None
    time: float


@dataclass(frozen=True)
class Links:
    """prev: (S,) int32 matched t-1 segment per t segment, -1 = none; score: (S,) float32, NaN = none.

    fragments: (E, 2) int32 (t segment, t-1 segment) pairs that share points but are not each
    other's link: the pieces of an object that split, merge or reshuffle between frames (foliage,
    a wall cut by a pillar). fragment_share: (E,) float32 the larger of the two segments' shares
    of those points. Empty unless `AssociationConfig.fragment_min_share` is in (0, 1].
    """

    prev: np.ndarray
    score: np.ndarray
    fragments: np.ndarray = field(default_factory=lambda: np.zeros((0, 2), np.int32))
    fragment_share: np.ndarray = field(default_factory=lambda: np.zeros(0, np.float32))


@dataclass(frozen=True)
class _Block:
    """The (valid t) x (valid t-1) block that association works on.

    va: (A,) and vb: (B,) segment ids; n_a: (A,), n_b: (B,) float64 point counts (>= 1);
    cw_a: (A, 3), cw_b: (B, 3) world centroids; vel_b: (B, 3) world velocity of each b's track,
    speed: (B,) its norm; dt: seconds from t-1 to t.
    """

    va: np.ndarray
    vb: np.ndarray
    n_a: np.ndarray
    n_b: np.ndarray
    cw_a: np.ndarray
    cw_b: np.ndarray
    vel_b: np.ndarray
    speed: np.ndarray
    dt: float


def associate(
    curr_points: np.ndarray,
    curr_seg_point: np.ndarray,
    curr: AssociationFrame,
    prev: AssociationFrame,
    prev_velocity: np.ndarray,
    sensor: SensorModel,
    config: AssociationConfig,
) -> Links:
    """Link the valid segments of `curr` to those of `prev`.

    curr_seg_point: (N,) valid-segment id per point of `curr`, -1 = none.
    prev_velocity: (S_{t-1}, 3) world velocity (m/s) of the track each t-1 segment belongs to.
    """
    n_curr, n_prev = len(curr.n_points), len(prev.n_points)
    links = Links(np.full(n_curr, -1, np.int32), np.full(n_curr, np.nan, np.float32))
    if n_curr == 0 or n_prev == 0 or curr.T_world_lidar is None or prev.T_world_lidar is None:
        return links
    T_prev_curr = np.linalg.inv(prev.T_world_lidar) @ curr.T_world_lidar
    # only valid segments take part: work on the (valid t) x (valid t-1) block
    va, vb = np.flatnonzero(curr.valid), np.flatnonzero(prev.valid)
    if len(va) == 0 or len(vb) == 0:
        return links
    by_segment = points_by_segment(curr_seg_point, n_curr)
    votes = vote_matrix(curr_points, curr_seg_point, n_curr, prev, T_prev_curr, sensor, va, vb, by_segment)
    vel_b = prev_velocity[vb]
    blk = _Block(
        va, vb, np.maximum(curr.n_points[va], 1).astype(np.float64), np.maximum(prev.n_points[vb], 1).astype(np.float64),
        curr.centroid_world[va], prev.centroid_world[vb], vel_b, np.linalg.norm(vel_b, axis=1),
        max(curr.time - prev.time, 1e-3),
    )
    share = votes / blk.n_a[:, None]  # (A, B) share of a's points voting for b, raised by motion votes
    # (A,) share of a's points, (B,) of b's, that a static object would explain: a moving object
    # leaves its place and lands on nothing
    static_share = share.sum(axis=1)
    vacated = votes.sum(axis=0) / blk.n_b < FIRST_LINK_STATIC
    vote_moving = partial(moving_votes, curr_points, curr_seg_point, n_curr, prev=prev,
                          T_prev_curr=T_prev_curr, sensor=sensor, by_segment=by_segment)
    # 1. overlap, with likely merges left out
    score = _overlap_score(votes, share, blk, config)
    # 2. moving tracks: predicted-centroid matching where the overlap is weak
    if config.use_motion_prediction:
        _add_motion_scores(score, share, blk, prev.T_world_lidar, vote_moving, config)
    # 3. gates: point counts must be comparable, centroids must be near after ego-motion
    ratio = _apply_gates(score, share, blk, config)
    # 4. one-to-one
    r, c = linear_sum_assignment(-score)
    ok = score[r, c] >= config.min_score
    links.prev[va[r[ok]]] = vb[c[ok]]
    links.score[va[r[ok]]] = score[r[ok], c[ok]]
    if config.use_motion_prediction:
        # 5. segments that land on nothing as static objects: a first link by a motion hypothesis
        rows, cols = _first_links(links, blk, ratio, (static_share < FIRST_LINK_STATIC, vacated), r[ok], c[ok],
                                  prev.T_world_lidar, vote_moving, config)
        # 6. objects that start moving (no velocity yet) or move across their own extent
        _link_leftovers(links, blk, ratio, rows, cols, config)
    return _with_fragments(links, votes, blk.n_a, blk.n_b, va, vb, config.fragment_min_share)


def _overlap_score(votes: np.ndarray, share: np.ndarray, blk: _Block, config: AssociationConfig) -> np.ndarray:
    """(A, B) float64 link score from the plain votes: 0 where a's share on b is under
    min_overlap or a's votes split between two t-1 segments (a likely merge)."""
    return _overlap_kernel(votes, share, blk.n_a, blk.n_b, config.min_overlap, config.ambiguity_ratio)


@njit(cache=True)
def _overlap_kernel(votes, share, n_a, n_b, min_overlap, ambiguity_ratio):  # pragma: no cover - numba
    """`_overlap_score` in one pass over the block (a dozen numpy passes over it cost 0.4 ms)."""
    n_rows, n_cols = votes.shape
    score = np.zeros((n_rows, n_cols))
    for i in range(n_rows):
        if n_cols >= 2:
            first = second = -np.inf  # the two largest shares of the row, ties counted twice
            for j in range(n_cols):
                v = share[i, j]
                if v > first:
                    second = first
                    first = v
                elif v > second:
                    second = v
            if second > ambiguity_ratio * first and second >= 0.1:
                continue  # a likely merge: the row stays 0
        for j in range(n_cols):
            if share[i, j] >= min_overlap:
                # votes over the larger of the two segments, so that the pieces of a split do not
                # tie with the whole at 1.0 (the smaller piece scores low and stays unlinked)
                score[i, j] = votes[i, j] / max(n_a[i], n_b[j])
    return score


def _add_motion_scores(
    score: np.ndarray,
    share: np.ndarray,
    blk: _Block,
    T_world_prev: np.ndarray,
    vote_moving: Callable[[np.ndarray, np.ndarray], np.ndarray],
    config: AssociationConfig,
) -> None:
    """Raise, in place, the weak scores of moving t-1 tracks to their predicted-centroid score,
    and score and share to the motion-compensated votes where those are higher.

    vote_moving(pairs, shift): `moving_votes` of (P, 2) (t, t-1) segment pairs, shifts (P, 3).
    """
    moving = blk.speed > 0.5
    if not moving.any():
        return
    mv = np.flatnonzero(moving)
    pred = blk.cw_b[mv] + blk.vel_b[mv] * blk.dt
    gate = _gate(blk.speed[mv], blk.dt, config)  # (M,) metres: wider for faster tracks
    cscore, ia, jb = _motion_candidates(score, share, blk.n_a, blk.n_b, blk.cw_a, blk.cw_b, mv, pred, gate, config.min_score,
                                        config.strong_share, config.max_height_change, config.max_point_ratio)
    if len(ia):
        shift = -(blk.vel_b[mv[jb]] * blk.dt) @ T_world_prev[:3, :3]  # world -> t-1 lidar frame: R^T d
        mvotes = vote_moving(np.stack([blk.va[ia], blk.vb[mv[jb]]], axis=1), shift)
        _take_motion_votes(cscore, share, ia, jb, mv, mvotes, blk.n_a, blk.n_b, config.min_overlap)
    _raise_weak(score, cscore, mv, config.min_score)


@njit(cache=True)
def _motion_candidates(score, share, n_a, n_b, cw_a, cw_b, mv, pred, gate, min_score, strong_share, max_dz,
                       max_ratio):  # pragma: no cover - numba
    """(A, M) predicted-centroid score of each t segment for each moving t-1 track (1 at the
    predicted centroid, 0 at the gate) and the pairs (ia, jb) worth motion-compensated votes:
    near the gate, left under the score or the strong-share gate by their plain votes (only there
    can motion votes change the outcome), and passing the height and point-count gates (pairs
    those turn down anyway cost no votes)."""
    n_rows, m = cw_a.shape[0], mv.shape[0]
    cscore = np.zeros((n_rows, m))
    near = np.zeros((n_rows, m), dtype=np.bool_)
    for i in range(n_rows):
        for k in range(m):
            b = mv[k]
            dx = cw_a[i, 0] - pred[k, 0]
            dy = cw_a[i, 1] - pred[k, 1]
            dist = np.sqrt(dx * dx + dy * dy)
            h = abs(cw_a[i, 2] - cw_b[b, 2])
            # a moving object keeps its height: a bollard under a crown is not the crown moved
            cscore[i, k] = 0.0 if h > max_dz else min(max(1.0 - dist / gate[k], 0.0), 1.0)
            ratio = n_a[i] / n_b[b]
            near[i, k] = ((dist < gate[k] + 1.5) and (score[i, b] < min_score or share[i, b] < strong_share)
                          and h <= max_dz and ratio <= max_ratio and ratio >= 1.0 / max_ratio)
    ia, jb = np.nonzero(near)
    return cscore, ia, jb


@njit(cache=True)
def _take_motion_votes(cscore, share, ia, jb, mv, mvotes, n_a, n_b, min_overlap):  # pragma: no cover
    """Raise, in place, cscore and share to the motion-compensated votes of pairs (ia, jb), which
    passed the height gate in `_motion_candidates`."""
    for p in range(ia.shape[0]):
        i, k = ia[p], jb[p]
        b = mv[k]
        mshare = mvotes[p] / n_a[i]
        if mshare >= min_overlap:
            cscore[i, k] = max(cscore[i, k], mvotes[p] / max(n_a[i], n_b[b]))
            share[i, b] = max(share[i, b], mshare)


@njit(cache=True)
def _raise_weak(score, cscore, mv, min_score):  # pragma: no cover - numba
    """Scores of moving tracks under min_score rise, in place, to their motion score."""
    for i in range(score.shape[0]):
        for k in range(mv.shape[0]):
            v = score[i, mv[k]]
            if v < min_score:
                score[i, mv[k]] = max(v, cscore[i, k])


def _gate(speed: np.ndarray, dt: float, config: AssociationConfig) -> np.ndarray:
    """(M,) metres a predicted centroid may miss by: max_centroid_distance plus `speed_gate` of
    the distance the track moves in dt (a fast car's centroid error grows with its motion: it
    speeds up, brakes, and the visible part of it changes with the view)."""
    return config.max_centroid_distance + config.speed_gate * speed * dt


def _unmatched(n: int, matched: np.ndarray, allowed: np.ndarray | None = None) -> np.ndarray:
    """Sorted indices in [0, n) not in `matched`, and where `allowed` (n,) bool is true."""
    free = np.ones(n, dtype=bool) if allowed is None else allowed.copy()
    free[matched] = False
    return np.flatnonzero(free)


def _first_links(
    links: Links,
    blk: _Block,
    ratio: np.ndarray,
    moved: tuple[np.ndarray, np.ndarray],
    rows: np.ndarray,
    cols: np.ndarray,
    T_world_prev: np.ndarray,
    vote_moving: Callable[[np.ndarray, np.ndarray], np.ndarray],
    config: AssociationConfig,
) -> tuple[np.ndarray, np.ndarray]:
    """Link, in place, unmatched t segments to unmatched t-1 segments by a motion hypothesis,
    where both moved as no static object would: `moved` ((A,) bool, (B,) bool) holds the t
    segments under FIRST_LINK_STATIC of whose points land on t-1 segments, and the t-1 segments
    that under FIRST_LINK_STATIC of their size in t points land on (a car has left its place; a
    reshuffled piece of foliage mostly has not). A pair needs FIRST_LINK_MIN_POINTS each, the
    t-1 centroid within `max_speed` x dt (+ max_centroid_distance) at the same height,
    comparable point counts, and FIRST_LINK_MIN_SHARE of a's points landing on b when moved back
    by the centroids' displacement; unique pairs go one-to-one (Hungarian on the
    motion-compensated score). Returns the block rows and columns matched so far."""
    free_a, free_b = _unmatched(len(blk.va), rows, moved[0]), _unmatched(len(blk.vb), cols, moved[1])
    if not (len(free_a) and len(free_b)):
        return rows, cols
    d = cdist(blk.cw_a[free_a, :2], blk.cw_b[free_b, :2])
    dz = np.abs(blk.cw_a[free_a, None, 2] - blk.cw_b[None, free_b, 2])
    rat = ratio[np.ix_(free_a, free_b)]
    reach = config.max_speed * blk.dt + config.max_centroid_distance
    near = (d <= reach) & (dz <= config.max_height_change) & (rat <= 1.5) & (rat >= 1.0 / 1.5)
    near &= (blk.n_a[free_a, None] >= FIRST_LINK_MIN_POINTS) & (blk.n_b[None, free_b] >= FIRST_LINK_MIN_POINTS)
    ia, jb = np.nonzero(near)
    if len(ia) == 0:
        return rows, cols
    a, b = free_a[ia], free_b[jb]
    shift = -(blk.cw_a[a] - blk.cw_b[b]) @ T_world_prev[:3, :3]  # world -> t-1 lidar frame: R^T d
    mvotes = vote_moving(np.stack([blk.va[a], blk.vb[b]], axis=1), shift)
    mscore = np.where(mvotes / blk.n_a[a] >= FIRST_LINK_MIN_SHARE, mvotes / np.maximum(blk.n_a[a], blk.n_b[b]), 0.0)
    score = np.zeros((len(free_a), len(free_b)))
    score[ia, jb] = mscore
    # a hypothesis that another one nearly matches is a repeated structure (fence posts, a row
    # of shrubs), not a motion
    if FIRST_LINK_UNIQUE > 0:
        second_b = np.sort(score, axis=1)[:, -2] if score.shape[1] > 1 else np.zeros(len(score))
        second_a = np.sort(score, axis=0)[-2] if score.shape[0] > 1 else np.zeros(score.shape[1])
        score[(second_b[:, None] > FIRST_LINK_UNIQUE * score) | (second_a[None, :] > FIRST_LINK_UNIQUE * score)] = 0.0
    r, c = linear_sum_assignment(-score)
    ok = score[r, c] >= config.min_score
    links.prev[blk.va[free_a[r[ok]]]] = blk.vb[free_b[c[ok]]]
    links.score[blk.va[free_a[r[ok]]]] = score[r[ok], c[ok]]
    return np.concatenate([rows, free_a[r[ok]]]), np.concatenate([cols, free_b[c[ok]]])


def _apply_gates(score: np.ndarray, share: np.ndarray, blk: _Block, config: AssociationConfig) -> np.ndarray:
    """Zero, in place, the scores of pairs whose point counts differ too much or, for weak
    matches, whose centroids jumped too far. Returns the (A, B) ratio n_a / n_b."""
    max_jump = config.max_centroid_distance + 1.0 + blk.speed * blk.dt * 2.0
    return _gates_kernel(score, share, blk.n_a, blk.n_b, blk.cw_a, blk.cw_b, max_jump, config.max_point_ratio,
                         config.strong_share)


@njit(cache=True)
def _gates_kernel(score, share, n_a, n_b, cw_a, cw_b, max_jump, max_ratio, strong_share):  # pragma: no cover
    n_rows, n_cols = score.shape
    ratio = np.empty((n_rows, n_cols))
    for i in range(n_rows):
        for j in range(n_cols):
            r = n_a[i] / n_b[j]
            ratio[i, j] = r
            dx = cw_a[i, 0] - cw_b[j, 0]
            dy = cw_a[i, 1] - cw_b[j, 1]
            dz = cw_a[i, 2] - cw_b[j, 2]
            # strong votes are geometric evidence already: the centroid of a large segment (a
            # wall, a hedge) moves by metres as the visible part changes, so only weak matches
            # face the jump gate
            jumped = np.sqrt(dx * dx + dy * dy + dz * dz) > max_jump[j] and not share[i, j] >= strong_share
            if r > max_ratio or r < 1.0 / max_ratio or jumped:
                score[i, j] = 0.0
    return ratio


def _link_leftovers(
    links: Links, blk: _Block, ratio: np.ndarray, rows: np.ndarray, cols: np.ndarray, config: AssociationConfig
) -> None:
    """Link, in place, the segments left unmatched (block rows/cols not in `rows`/`cols`) by world
    centroid, only where the match is mutual and unambiguous."""
    free_a, free_b = _unmatched(len(blk.va), rows), _unmatched(len(blk.vb), cols)
    if not (len(free_a) and len(free_b)):
        return
    d = cdist(blk.cw_a[free_a, :2], blk.cw_b[free_b, :2])
    dz = np.abs(blk.cw_a[free_a, None, 2] - blk.cw_b[None, free_b, 2])
    rat = ratio[np.ix_(free_a, free_b)]
    d = np.where((dz < 0.3) & (rat < 1.5) & (rat > 1 / 1.5), d, np.inf)
    near_b = np.argmin(d, axis=1)
    near_a = np.argmin(d, axis=0)
    # the second nearest candidate of each row and column: a match is ambiguous when another one
    # is nearly as close
    second_b = np.partition(d, 1, axis=1)[:, 1] if d.shape[1] > 1 else np.full(len(d), np.inf)
    second_a = np.partition(d, 1, axis=0)[1] if d.shape[0] > 1 else np.full(d.shape[1], np.inf)
    i = np.arange(len(near_b))
    dij = d[i, near_b]
    take = (np.isfinite(dij) & (dij <= config.max_centroid_distance) & (near_a[near_b] == i)
            & (np.minimum(second_b, second_a[near_b]) >= 2.0 * dij + 0.5))
    links.prev[blk.va[free_a[take]]] = blk.vb[free_b[near_b[take]]]
    links.score[blk.va[free_a[take]]] = (1.0 - dij[take] / config.max_centroid_distance) * 0.5


def _with_fragments(
    links: Links, votes: np.ndarray, n_a: np.ndarray, n_b: np.ndarray, va: np.ndarray, vb: np.ndarray,
    min_share: float,
) -> Links:
    """`links` plus the (t, t-1) pairs not linked to each other where either segment has at least
    min_share of its points on the other (votes: (A, B) plain ego-motion votes, before any gate)."""
    if not 0.0 < min_share <= 1.0:
        return links
    ia, jb, mutual = _mutual_pairs(votes, n_a, n_b, min_share)
    a, b = va[ia], vb[jb]
    keep = links.prev[a] != b
    return replace(links, fragments=np.stack([a[keep], b[keep]], axis=1).astype(np.int32),
                   fragment_share=mutual[keep].astype(np.float32))


@njit(cache=True)
def _mutual_pairs(votes, n_a, n_b, min_share):  # pragma: no cover - numba
    """The block's pairs, in row order, where either segment has min_share of its points on the
    other (capped at 1: a pixel may take 2 points), and that share."""
    n_rows, n_cols = votes.shape
    ia = np.empty(n_rows * n_cols, dtype=np.int64)
    jb = np.empty(n_rows * n_cols, dtype=np.int64)
    mutual = np.empty(n_rows * n_cols)
    n = 0
    for i in range(n_rows):
        for j in range(n_cols):
            v = votes[i, j]
            if v == 0.0:
                continue
            m = min(max(v / n_a[i], v / n_b[j]), 1.0)
            if m >= min_share:
                ia[n], jb[n], mutual[n] = i, j, m
                n += 1
    return ia[:n], jb[:n], mutual[:n]
