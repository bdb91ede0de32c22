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
from pipeline.range_image import fast_atan2
from pipeline.sensors import SensorModel

# At most this many points of a segment vote (an evenly strided subset, its votes scaled to the
# segment's size): a 0.3 share is then known within a few percent, and a 20k-point wall costs
# no more than a car. 256 and 128 gave the same quality on the three labelled real clips as 512
# and 256, in two thirds of the time (docs/perception.md).
VOTE_POINTS = 256
MOTION_VOTE_POINTS = 128  # the same in each motion-compensated pair
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
class BeamLookup:
    """Nearest beam of an elevation without a search: beams_asc (nb,) float64 elevations (rad,
    the rows bottom up: ascending); below (Q,) int64 per bin of `step` rad from `low`, a beam below every elevation of
    the bin (the last beam under the bin's low edge, one lower for rounding, within [0, nb - 2])."""

    beams_asc: np.ndarray
    below: np.ndarray
    low: float
    inv_step: float


LOOKUP_STEP = 2e-4  # rad, under a tenth of the closest beams of the presets (OS-128: 2.7e-3)
_LOOKUPS: dict[tuple, BeamLookup] = {}


def beam_lookup(sensor: SensorModel) -> BeamLookup:
    """The sensor's BeamLookup, built once per set of elevations."""
    key = tuple(sensor.elevations_deg)
    out = _LOOKUPS.get(key)
    if out is None:
        beams = np.ascontiguousarray(sensor.elevations_rad()[::-1], dtype=np.float64)  # rows bottom up
        low = float(beams[0]) - 0.01
        edges = low + LOOKUP_STEP * np.arange(int((beams[-1] + 0.01 - low) / LOOKUP_STEP) + 2)
        below = np.clip(np.searchsorted(beams, edges) - 2, 0, max(len(beams) - 2, 0)).astype(np.int64)
        out = _LOOKUPS[key] = BeamLookup(beams, below, low, 1.0 / LOOKUP_STEP)
    return out


@njit(cache=True, inline="always")
def _land(x0, y0, z0, R, t, beams_asc, below, low, inv_step, h, w):  # pragma: no cover - numba
    """Move one point with (R, t) and return its (row, col, range) in t-1's range image
    (nearest beam, azimuth column), as `range_image.project` would place it. The bin of the
    point's elevation gives a beam below it, and at most a step or two up gives the beams around
    it: a binary search per point took a third of the votes' time."""
    nb = beams_asc.shape[0]
    x = R[0, 0] * x0 + R[0, 1] * y0 + R[0, 2] * z0 + t[0]
    y = R[1, 0] * x0 + R[1, 1] * y0 + R[1, 2] * z0 + t[1]
    z = R[2, 0] * x0 + R[2, 1] * y0 + R[2, 2] * z0 + t[2]
    el = fast_atan2(np.float32(z), np.float32(np.sqrt(x * x + y * y)))
    k = below[min(max(int((el - low) * inv_step), 0), below.shape[0] - 1)]
    while k + 1 < nb - 1 and beams_asc[k + 1] < el:
        k += 1
    # the nearer of the beams below and above (ties go up), as project's nearest beam
    asc = k if (el - beams_asc[k]) < (beams_asc[min(k + 1, nb - 1)] - el) else min(k + 1, nb - 1)
    row = nb - 1 - asc
    col = int(np.floor((0.5 - fast_atan2(np.float32(y), np.float32(x)) * (0.5 / np.pi)) * w))
    col = col - w if col >= w else col
    col = col + w if col < 0 else col
    return row, col, np.sqrt(x * x + y * y + z * z)


@njit(cache=True)
def _votes(points, order, starts, rows, seg_pixel, cols, pix_range, R, t, beams_asc, below, low, inv_step, max_points):  # pragma: no cover
    """Move the points of segments `rows` with (R, t), project them onto t-1's range image and
    count them for the t-1 segment there when the ranges agree: (len(rows), len(cols)) float64,
    cols[b] the column of t-1 segment b (-1: none). A segment of more than `max_points` points
    votes with an evenly strided subset, scaled to its size."""
    h, w = seg_pixel.shape
    votes = np.zeros((rows.shape[0], cols.max() + 1), dtype=np.float64)
    for k in range(rows.shape[0]):
        a = rows[k]
        size = starts[a + 1] - starts[a]
        stride = max(1, (size + max_points - 1) // max_points)  # at most max_points points
        weight = size / ((size + stride - 1) // stride) if size else 0.0
        for j in range(starts[a], starts[a + 1], stride):
            i = order[j]
            row, col, r_proj = _land(np.float64(points[i, 0]), np.float64(points[i, 1]), np.float64(points[i, 2]),
                                     R, t, beams_asc, below, low, inv_step, h, w)
            b = seg_pixel[row, col]
            if b >= 0 and cols[b] >= 0 and abs(r_proj - pix_range[row, col]) <= 0.3 + 0.03 * r_proj:
                votes[k, cols[b]] += weight
    return votes


@njit(cache=True)
def _pair_votes(points, order, starts, pair_a, pair_b, shift, seg_pixel, pix_range, R, t, beams_asc, below, low,
                inv_step, max_points):  # pragma: no cover - numba
    """Votes of segment pair_a[k]'s points for pair_b[k] after moving them by (R, t) and then by
    shift[k] (in t-1's lidar frame: the b track's own motion undone). A segment of more than
    `max_points` points votes with an evenly strided subset, scaled to its size (a share of 0.3
    is then known within a few percent, and a wall's 20k points cost as much as a car's)."""
    h, w = seg_pixel.shape
    out = np.zeros(pair_a.shape[0], dtype=np.float64)
    for k in range(pair_a.shape[0]):
        a, b = pair_a[k], pair_b[k]
        tk = t + shift[k]
        size = starts[a + 1] - starts[a]
        stride = max(1, (size + max_points - 1) // max_points)  # at most max_points points
        n = 0
        used = 0
        for j in range(starts[a], starts[a + 1], stride):
            i = order[j]
            used += 1
            row, col, r_proj = _land(np.float64(points[i, 0]), np.float64(points[i, 1]), np.float64(points[i, 2]),
                                     R, tk, beams_asc, below, low, inv_step, h, w)
            if seg_pixel[row, col] == b and abs(r_proj - pix_range[row, col]) <= 0.3 + 0.03 * r_proj:
                n += 1
        out[k] = n * size / used if used else 0.0
    return out


@njit(cache=True)
def _points_by_segment(seg_point, n_seg):  # pragma: no cover - numba
    """Counting sort of the points by segment: (order (M,) int64 point indices of segments
    0, 1, ..., starts (n_seg + 1,) int64 offsets of each segment in `order`); -1 left out."""
    starts = np.zeros(n_seg + 1, dtype=np.int64)
    for s in seg_point:
        if s >= 0:
            starts[s + 1] += 1
    for k in range(n_seg):
        starts[k + 1] += starts[k]
    fill = starts[:-1].copy()
    order = np.empty(starts[n_seg], dtype=np.int64)
    for i in range(seg_point.shape[0]):
        s = seg_point[i]
        if s >= 0:
            order[fill[s]] = i
            fill[s] += 1
    return order, starts


def _lookup_args(sensor: SensorModel) -> tuple:
    lk = beam_lookup(sensor)
    return lk.beams_asc, lk.below, lk.low, lk.inv_step


def moving_votes(
    points: np.ndarray,
    seg_point: np.ndarray,
    n_curr: int,
    pairs: np.ndarray,
    shift_prev: np.ndarray,
    prev: AssociationFrame,
    T_prev_curr: np.ndarray,
    sensor: SensorModel,
    by_segment: tuple[np.ndarray, np.ndarray] | None = None,
) -> np.ndarray:
    """(P,) float64 motion-compensated votes of t segment pairs[:, 0] for t-1 segment pairs[:, 1].

    shift_prev: (P, 3) displacement (t-1 lidar frame) added after the ego-motion: minus the
    motion of the t-1 track over dt, so that a moving object's points land where it was.
    by_segment: `_points_by_segment(seg_point, n_curr)` when the caller has it already.
    """
    if len(pairs) == 0:
        return np.zeros(0, np.float64)
    order, starts = by_segment if by_segment is not None else _points_by_segment(seg_point, n_curr)
    T = np.asarray(T_prev_curr, dtype=np.float64)
    return _pair_votes(
        points, order, starts, pairs[:, 0].astype(np.int64), pairs[:, 1].astype(np.int64),
        np.ascontiguousarray(shift_prev, dtype=np.float64), prev.seg_pixel, prev.range,
        np.ascontiguousarray(T[:3, :3]), np.ascontiguousarray(T[:3, 3]), *_lookup_args(sensor), MOTION_VOTE_POINTS,
    )


def vote_matrix(
    points: np.ndarray,
    seg_point: np.ndarray,
    n_curr: int,
    prev: AssociationFrame,
    T_prev_curr: np.ndarray,
    sensor: SensorModel,
    rows: np.ndarray,
    cols: np.ndarray,
    by_segment: tuple[np.ndarray, np.ndarray] | None = None,
) -> np.ndarray:
    """(len(rows), len(cols)) float64 votes: points of t segment rows[i] that land on t-1 segment
    cols[j] (segments of more than VOTE_POINTS points vote with a subset, scaled)."""
    if len(rows) == 0 or len(cols) == 0:
        return np.zeros((len(rows), len(cols)), dtype=np.float64)
    order, starts = by_segment if by_segment is not None else _points_by_segment(seg_point, n_curr)
    col_of = np.full(len(prev.n_points), -1, dtype=np.int64)
    col_of[cols] = np.arange(len(cols))
    T = np.asarray(T_prev_curr, dtype=np.float64)
    return _votes(
        points, order, starts, np.asarray(rows, dtype=np.int64), prev.seg_pixel, col_of, prev.range,
        np.ascontiguousarray(T[:3, :3]), np.ascontiguousarray(T[:3, 3]), *_lookup_args(sensor), VOTE_POINTS,
    )


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
    by_segment = _points_by_segment(curr_seg_point, n_curr)
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
    cscore, dz, ia, jb = _motion_candidates(score, share, blk.n_a, blk.n_b, blk.cw_a, blk.cw_b, mv, pred, gate, config.min_score,
                                            config.strong_share, config.max_height_change, config.max_point_ratio)
    if len(ia):
        shift = -(blk.vel_b[mv[jb]] * blk.dt) @ T_world_prev[:3, :3]  # world -> t-1 lidar frame: R^T d
        mvotes = vote_moving(np.stack([blk.va[ia], blk.vb[mv[jb]]], axis=1), shift)
        _take_motion_votes(cscore, share, dz, ia, jb, mv, mvotes, blk.n_a, blk.n_b, config.min_overlap,
                           config.max_height_change)
    _raise_weak(score, cscore, mv, config.min_score)


@njit(cache=True)
def _motion_candidates(score, share, n_a, n_b, cw_a, cw_b, mv, pred, gate, min_score, strong_share, max_dz,
                       max_ratio):  # pragma: no cover - numba
    """(A, M) predicted-centroid score of each t segment for each moving t-1 track (1 at the
    predicted centroid, 0 at the gate), (A, M) height change, and the pairs (ia, jb) worth
    motion-compensated votes: near the gate, left under the score or the strong-share gate by
    their plain votes (only there can motion votes change the outcome), and passing the height
    and point-count gates (pairs those turn down anyway cost no votes)."""
    n_rows, m = cw_a.shape[0], mv.shape[0]
    cscore = np.zeros((n_rows, m))
    dz = np.empty((n_rows, m))
    near = np.zeros((n_rows, m), dtype=np.bool_)
    for i in range(n_rows):
        for k in range(m):
            b = mv[k]
            dx = cw_a[i, 0] - pred[k, 0]
            dy = cw_a[i, 1] - pred[k, 1]
            dist = np.sqrt(dx * dx + dy * dy)
            h = abs(cw_a[i, 2] - cw_b[b, 2])
            dz[i, k] = h
            # a moving object keeps its height: a bollard under a crown is not the crown moved
            cscore[i, k] = 0.0 if h > max_dz else min(max(1.0 - dist / gate[k], 0.0), 1.0)
            ratio = n_a[i] / n_b[b]
            near[i, k] = ((dist < gate[k] + 1.5) and (score[i, b] < min_score or share[i, b] < strong_share)
                          and h <= max_dz and ratio <= max_ratio and ratio >= 1.0 / max_ratio)
    ia, jb = np.nonzero(near)
    return cscore, dz, ia, jb


@njit(cache=True)
def _take_motion_votes(cscore, share, dz, ia, jb, mv, mvotes, n_a, n_b, min_overlap, max_dz):  # pragma: no cover
    """Raise, in place, cscore and share to the motion-compensated votes of pairs (ia, jb)."""
    for p in range(ia.shape[0]):
        i, k = ia[p], jb[p]
        b = mv[k]
        mshare = mvotes[p] / n_a[i]
        if mshare >= min_overlap and dz[i, k] <= max_dz:
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
