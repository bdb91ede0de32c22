"""Votes: the points of a frame's segments moved into the previous frame's range image (with
the ego-motion, and for a moving track with its own motion undone) and counted for the segment
whose pixel they land on when the ranges agree. Association (`pipeline.association`) scores its
links from them.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numba import njit

from pipeline.range_image import fast_atan2
from pipeline.sensors import SensorModel

if TYPE_CHECKING:
    from pipeline.association import AssociationFrame

# At most this many points of a segment vote (an evenly strided subset, its votes scaled to the
# segment's size): a 0.3 share is then known within a few percent, and a 20k-point wall costs
# no more than a car. 256 and 128 gave the same quality on the three labelled real clips as 512
# and 256, in two thirds of the time (docs/perception.md).
VOTE_POINTS = 256
MOTION_VOTE_POINTS = 128  # the same in each motion-compensated pair


@dataclass(frozen=True)
class BeamLookup:
    """Nearest beam of an elevation without a search. beams_asc: (nb,) float64 elevations (rad)
    of the rows bottom up (ascending); below: (Q,) int64 per bin of LOOKUP_STEP rad from `low`, a
    beam under every elevation of the bin (the last beam under the bin's low edge, one lower for
    rounding, within [0, nb - 2]); inv_step: 1 / LOOKUP_STEP."""

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
def points_by_segment(seg_point, n_seg):  # pragma: no cover - numba
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
    by_segment: `points_by_segment(seg_point, n_curr)` when the caller has it already.
    """
    if len(pairs) == 0:
        return np.zeros(0, np.float64)
    order, starts = by_segment if by_segment is not None else points_by_segment(seg_point, n_curr)
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
    order, starts = by_segment if by_segment is not None else points_by_segment(seg_point, n_curr)
    col_of = np.full(len(prev.n_points), -1, dtype=np.int64)
    col_of[cols] = np.arange(len(cols))
    T = np.asarray(T_prev_curr, dtype=np.float64)
    return _votes(
        points, order, starts, np.asarray(rows, dtype=np.int64), prev.seg_pixel, col_of, prev.range,
        np.ascontiguousarray(T[:3, :3]), np.ascontiguousarray(T[:3, 3]), *_lookup_args(sensor), VOTE_POINTS,
    )
