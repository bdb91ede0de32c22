"""Frame-to-frame association of segments into tracks.

For frame t, every point of a valid segment is moved into frame t-1 with the ego-motion
(`T_prev_curr = inv(T_world_prev) @ T_world_curr`) and projected into t-1's range image. A point
votes for the t-1 segment owning that pixel when its range agrees with the pixel's range. The link
score of (a, b) is votes(a -> b) / max(n_a, n_b). Tracks that move (constant-velocity
state) are also matched by predicted centroid when the overlap is weak. Pairs are solved one-to-one
with the Hungarian method. Precision beats recall (a wrong link teaches the model a wrong equality),
so a segment whose votes split between two t-1 segments (a merge) or whose point count jumps is
left unlinked.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit
from scipy.optimize import linear_sum_assignment
from scipy.spatial.distance import cdist

from pipeline.config import AssociationConfig
from pipeline.range_image import fast_atan2
from pipeline.sensors import SensorModel


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
    """prev: (S,) int32 matched t-1 segment per t segment, -1 = none; score: (S,) float32, NaN = none."""

    prev: np.ndarray
    score: np.ndarray


@njit(cache=True)
def _votes(points, seg_point, n_curr, seg_pixel, pix_range, R, t, beams_asc, n_prev):  # pragma: no cover - numba
    """Move each segment point with (R, t), project it onto t-1's range image (nearest beam,
    azimuth column) and count it for the t-1 segment there when the ranges agree."""
    h, w = seg_pixel.shape
    nb = beams_asc.shape[0]
    votes = np.zeros((n_curr, n_prev), dtype=np.int64)
    inv_two_pi = 0.5 / np.pi
    for i in range(points.shape[0]):
        a = seg_point[i]
        if a < 0:
            continue
        x0 = np.float64(points[i, 0])
        y0 = np.float64(points[i, 1])
        z0 = np.float64(points[i, 2])
        x = R[0, 0] * x0 + R[0, 1] * y0 + R[0, 2] * z0 + t[0]
        y = R[1, 0] * x0 + R[1, 1] * y0 + R[1, 2] * z0 + t[1]
        z = R[2, 0] * x0 + R[2, 1] * y0 + R[2, 2] * z0 + t[2]
        el = fast_atan2(np.float32(z), np.float32(np.sqrt(x * x + y * y)))
        # nearest beam (beams ascending), as `elevation_rows`
        pos = np.searchsorted(beams_asc, el)
        pos = min(max(pos, 1), nb - 1)
        asc = pos - 1 if (el - beams_asc[pos - 1]) < (beams_asc[pos] - el) else pos
        row = nb - 1 - asc
        col = int(np.floor((0.5 - fast_atan2(np.float32(y), np.float32(x)) * inv_two_pi) * w)) % w
        b = seg_pixel[row, col]
        if b < 0:
            continue
        r_proj = np.sqrt(x * x + y * y + z * z)
        if abs(r_proj - pix_range[row, col]) <= 0.3 + 0.03 * r_proj:
            votes[a, b] += 1
    return votes


def vote_matrix(
    points: np.ndarray,
    seg_point: np.ndarray,
    n_curr: int,
    prev: AssociationFrame,
    T_prev_curr: np.ndarray,
    sensor: SensorModel,
) -> np.ndarray:
    """(S_t, S_{t-1}) int64 votes: points of each t segment that land on each t-1 segment."""
    n_prev = len(prev.n_points)
    if n_curr == 0 or n_prev == 0:
        return np.zeros((n_curr, n_prev), dtype=np.int64)
    T = np.asarray(T_prev_curr, dtype=np.float64)
    return _votes(
        points, seg_point, n_curr, prev.seg_pixel, prev.range, np.ascontiguousarray(T[:3, :3]),
        np.ascontiguousarray(T[:3, 3]), np.ascontiguousarray(sensor.elevations_rad()[::-1]), n_prev,
    )


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
    votes = vote_matrix(curr_points, curr_seg_point, n_curr, prev, T_prev_curr, sensor)[np.ix_(va, vb)]
    n_a = np.maximum(curr.n_points[va], 1).astype(np.float64)
    n_b = np.maximum(prev.n_points[vb], 1).astype(np.float64)
    share = votes / n_a[:, None]  # (A, B) share of a's points voting for b
    # link score: votes over the larger of the two segments, so that the pieces of a split do not
    # tie with the whole at 1.0 (the smaller piece scores low and stays unlinked)
    overlap = votes / np.maximum(n_a[:, None], n_b[None, :])

    # 1. ambiguity: a segment whose votes split between two t-1 segments is a likely merge
    if len(vb) >= 2:
        top2 = np.sort(share, axis=1)[:, -2:]
        ambiguous = (top2[:, 0] > 0.5 * top2[:, 1]) & (top2[:, 0] >= 0.1)
        overlap[ambiguous] = 0.0
    score = np.where(share >= config.min_overlap, overlap, 0.0)

    # 2. moving tracks: predicted-centroid matching where the overlap is weak
    dt = max(curr.time - prev.time, 1e-3)
    cw_a, cw_b, vel_b = curr.centroid_world[va], prev.centroid_world[vb], prev_velocity[vb]
    speed = np.linalg.norm(vel_b, axis=1)
    if config.use_motion_prediction:
        moving = speed > 0.5
        if moving.any():
            pred = cw_b[moving] + vel_b[moving] * dt
            dist = cdist(cw_a[:, :2], pred[:, :2])
            cscore = np.clip(1.0 - dist / config.max_centroid_distance, 0.0, 1.0)
            sub = score[:, moving]
            score[:, moving] = np.where(sub < config.min_score, np.maximum(sub, cscore), sub)

    # 3. gates: point counts must be comparable, centroids must be near after ego-motion
    ratio = n_a[:, None] / n_b[None, :]
    bad_ratio = (ratio > config.max_point_ratio) | (ratio < 1.0 / config.max_point_ratio)
    max_jump = config.max_centroid_distance + 1.0 + speed[None, :] * dt * 2.0
    jump = cdist(cw_a, cw_b)
    score[bad_ratio | (jump > max_jump)] = 0.0

    # 4. one-to-one
    r, c = linear_sum_assignment(-score)
    ok = score[r, c] >= config.min_score
    links.prev[va[r[ok]]] = vb[c[ok]]
    links.score[va[r[ok]]] = score[r[ok], c[ok]]

    # 5. objects that start moving (no velocity yet) or move across their own extent: match the
    # leftovers by world centroid, only where the match is mutual and unambiguous
    if config.use_motion_prediction:
        free_a = np.setdiff1d(np.arange(len(va)), r[ok])
        free_b = np.setdiff1d(np.arange(len(vb)), c[ok])
        if len(free_a) and len(free_b):
            d = cdist(cw_a[free_a, :2], cw_b[free_b, :2])
            dz = np.abs(cw_a[free_a, None, 2] - cw_b[None, free_b, 2])
            rat = ratio[np.ix_(free_a, free_b)]
            d = np.where((dz < 0.3) & (rat < 1.5) & (rat > 1 / 1.5), d, np.inf)
            near_b = np.argmin(d, axis=1)
            near_a = np.argmin(d, axis=0)
            for i, j in enumerate(near_b):
                dij = d[i, j]
                if not np.isfinite(dij) or dij > config.max_centroid_distance or near_a[j] != i:
                    continue
                second = min(np.partition(d[i], 1)[1] if d.shape[1] > 1 else np.inf,
                             np.partition(d[:, j], 1)[1] if d.shape[0] > 1 else np.inf)
                if second < 2.0 * dij + 0.5:
                    continue  # another candidate is nearly as close: ambiguous
                links.prev[va[free_a[i]]] = vb[free_b[j]]
                links.score[va[free_a[i]]] = float(1.0 - dij / config.max_centroid_distance) * 0.5
    return links
