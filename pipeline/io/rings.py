"""Ring (beam row) recovery from scan order or a ring field, and a check of any ring layout.

Rows follow docs/conventions.md: row 0 is the top beam.

- **Scan order** (`scan_order_rings`): a KITTI `.bin` stores one laser's revolution after the
  other, so a new beam starts where the azimuth wraps around (drops by more than half a turn).
  The segments are then ordered by elevation to make row 0 the top beam. Clouds without scan
  order get their rows from their elevations (`pipeline.io.beams`).
- **Ring field** (`rows_from_ring_field`): a source's ring numbers, turned top-down.

`check_rings` measures how well rows match lasers without ground truth: it fits each row's laser
origin height `h` (z = h + rho tan(e), the HDL-64E lasers sit ~0.2 m above the frame origin) and
counts the points whose corrected elevation lies more than half the local beam spacing from their
row's median in the same azimuth sector, towards a neighbouring row.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from pipeline.range_image import fast_atan2

TWO_PI = 2.0 * np.pi


@dataclass(frozen=True)
class RingCheck:
    """How well rows match lasers (see `check_rings`).

    rows:            number of rows that hold points.
    row_elevation:   (R,) float64 median corrected elevation per row, degrees (NaN = empty row).
    origin_height:   (R,) float64 fitted laser origin height per row, metres.
    monotonic:       row medians strictly decrease from row 0 down.
    wrong:           (N,) bool, point lies nearer a neighbouring row than its own (see module doc).
    wrong_fraction:  wrong.mean().
    """

    rows: int
    row_elevation: np.ndarray
    origin_height: np.ndarray
    monotonic: bool
    wrong: np.ndarray
    wrong_fraction: float


@njit(cache=True)
def _clockwise(points):  # pragma: no cover - numba
    """(N,) float32 azimuth in [0, 2 pi) of points stored clockwise or counter-clockwise, made
    counter-clockwise (most steps between consecutive points turn one way: that is the storage)."""
    n = points.shape[0]
    az = np.empty(n, dtype=np.float32)
    two_pi = np.float32(TWO_PI)
    turn = 0
    for i in range(n):
        a = fast_atan2(points[i, 1], points[i, 0])
        az[i] = a + two_pi if a < 0 else a
        if i:
            d = az[i] - az[i - 1]
            d = d - two_pi if d > np.pi else (d + two_pi if d < -np.pi else d)
            turn += 1 if d > 0 else (-1 if d < 0 else 0)
    if turn < 0:
        for i in range(n):
            az[i] = two_pi - az[i] if az[i] > 0 else az[i]
    return az


@njit(cache=True)
def _wrap_segments(points, az, cut, max_segments):  # pragma: no cover - numba
    """Scan-order segments from the cut: (N,) int32 segment id (a new one where the azimuth,
    measured from `cut`, drops by more than half a turn), (S,) counts and (S,) mean tan of the
    elevation; S = 0 when more than `max_segments` show (not a scan order)."""
    n = points.shape[0]
    seg = np.empty(n, dtype=np.int32)
    counts = np.zeros(max_segments, dtype=np.int64)
    sums = np.zeros(max_segments, dtype=np.float64)
    two_pi = np.float32(TWO_PI)
    k = 0
    prev = np.float32(0.0)
    for i in range(n):
        b = az[i] - cut
        b = b + two_pi if b < 0 else b
        if i and b - prev < -np.pi:
            k += 1
            if k >= max_segments:
                return seg, counts[:0], sums[:0]
        prev = b
        seg[i] = k
        x, y, z = points[i, 0], points[i, 1], points[i, 2]
        counts[k] += 1
        sums[k] += z / max(np.sqrt(x * x + y * y), 1e-6)
    counts = counts[: k + 1]
    return seg, counts, sums[: k + 1] / np.maximum(counts, 1)


def _azimuth(points: np.ndarray) -> np.ndarray:
    """(N,) float64 azimuth in [0, 2 pi), counter-clockwise from +x."""
    p = points.astype(np.float64, copy=False)
    return np.mod(np.arctan2(p[:, 1], p[:, 0]), TWO_PI)


def _elevation(points: np.ndarray) -> np.ndarray:
    """(N,) float64 elevation in radians."""
    p = points.astype(np.float64, copy=False)
    return np.arctan2(p[:, 2], np.hypot(p[:, 0], p[:, 1]))


def segment_medians(values: np.ndarray, seg: np.ndarray, n_seg: int) -> np.ndarray:
    """(n_seg,) median of `values` per segment id `seg` (NaN for empty segments)."""
    order = np.lexsort((values, seg))
    sv, ss = values[order], seg[order]
    counts = np.bincount(ss, minlength=n_seg)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    out = np.full(n_seg, np.nan)
    have = counts > 0
    lo = starts[have] + (counts[have] - 1) // 2
    hi = starts[have] + counts[have] // 2
    out[have] = 0.5 * (sv[lo] + sv[hi])
    return out


def _merge_fragments(counts: np.ndarray, elevation: np.ndarray) -> np.ndarray:
    """(S,) new dense id of each scan-order segment: tiny ones (azimuth jitter across the cut)
    join the neighbour of closer elevation; (S,) counts and mean elevations (any monotonic measure)."""
    n_seg = len(counts)
    target = np.arange(n_seg)
    if n_seg < 2:
        return target
    min_len = max(4, int(0.05 * np.median(counts)))
    for s in np.flatnonzero(counts < min_len):  # loop over a few segments, not points
        prev, nxt = s - 1, s + 1
        d_prev = abs(elevation[s] - elevation[prev]) if prev >= 0 and counts[prev] >= min_len else np.inf
        d_next = abs(elevation[s] - elevation[nxt]) if nxt < n_seg and counts[nxt] >= min_len else np.inf
        if np.isfinite(d_prev) or np.isfinite(d_next):
            target[s] = prev if d_prev <= d_next else nxt
    # resolve chains and renumber densely in scan order
    return np.unique(target[target], return_inverse=True)[1]


def _join_split_rings(target: np.ndarray, seg: np.ndarray, az: np.ndarray, counts: np.ndarray) -> np.ndarray:
    """`target` (S,) with consecutive merged segments joined where one laser's revolution was cut
    in two (a stray point among its returns wraps the azimuth): the two parts cover different
    azimuths (at most one, or a tenth, of the 10-degree sectors holding two points of the smaller part hold
    two of the other; two lasers see the same objects) and together hold no more points than
    1.15 x the median segment. seg (N,) scan-order segment and az (N,) azimuth of every point,
    counts (S,) points per segment. Renumbered densely."""
    found = int(target.max()) + 1
    if found < 3:
        return target
    w = np.bincount(target, weights=counts, minlength=found)
    small = w[:-1] + w[1:] <= 1.15 * np.median(w)
    if not small.any():
        return target
    sector = np.minimum((az * (36.0 / TWO_PI)).astype(np.int64), 35)
    occupied = np.bincount(target[seg] * 36 + sector, minlength=found * 36).reshape(found, 36) >= 2
    both = (occupied[:-1] & occupied[1:]).sum(axis=1)
    least = np.maximum(np.minimum(occupied[:-1].sum(axis=1), occupied[1:].sum(axis=1)), 1)
    join = small & (both <= np.maximum(1, 0.1 * least))  # the sector where the cut lies holds both
    group = np.concatenate([[0], np.cumsum(~join)])  # (found,) new id of each merged segment
    return group[target]


def _repeated_runs(elevation: np.ndarray) -> np.ndarray | None:
    """(S,) row of each scan-order segment given their mean elevations (S,) (any monotonic
    measure): its place in its run when the segments run from top to bottom (or back) more than
    once with the same beams (a scan written twice into one file, frames accumulated), else its
    own index; None when the runs differ in count or beams (not one sensor's scan order). A
    restart is a step of more than half the elevation span."""
    s = len(elevation)
    d = np.diff(elevation)
    span = float(elevation.max() - elevation.min()) if s else 0.0
    restart = np.flatnonzero(np.abs(d) > 0.5 * span) + 1 if s > 2 else np.zeros(0, np.int64)
    if len(restart) == 0:
        return np.arange(s)
    starts = np.concatenate([[0], restart])
    sizes = np.diff(np.append(starts, s))
    if np.any(sizes != sizes[0]) or sizes[0] < 2:
        return None
    runs = elevation.reshape(len(sizes), sizes[0])
    spacing = float(np.median(np.abs(np.diff(runs[0]))))
    if np.max(np.abs(runs - runs[0])) > 0.5 * spacing:
        return None
    return np.arange(s) % sizes[0]


# More scan-order segments than this are no scan order (an unordered cloud wraps at every point).
MAX_SEGMENTS = 1024


def scan_order_rings(points: np.ndarray, n_rings: int | None = None) -> tuple[np.ndarray | None, int]:
    """Rows from scan order: ((N,) int64 row 0 = top, or None when the order shows no rings; found).

    A layout is accepted when the segment count equals `n_rings` (any count when None) and the
    segments' mean elevations fall (or rise, then they are reversed) monotonically. The cut is
    tried at azimuth 0 (KITTI) and pi; counter-clockwise and clockwise storage are both accepted.
    """
    n = len(points)
    if n < 2:
        return None, 0
    pts = np.ascontiguousarray(points, dtype=np.float32)
    az = _clockwise(pts)
    first_found = 0
    for cut in (0.0, np.pi):
        seg, counts, elevation = _wrap_segments(pts, az, np.float32(cut), MAX_SEGMENTS)
        if len(counts) == 0:
            continue
        target = _merge_fragments(counts, elevation)
        target = _join_split_rings(target, seg, az, counts)
        merged = np.bincount(target, weights=elevation * counts) / np.bincount(target, weights=counts)
        repeat = _repeated_runs(merged)
        if repeat is None:
            continue
        target, merged = repeat[target], merged[: int(repeat.max()) + 1]
        found = int(target.max()) + 1
        first_found = first_found or found
        if found < 2 or (n_rings is not None and found != n_rings):
            continue
        d = np.diff(merged)
        if np.mean(d < 0) >= 0.9:
            return target[seg], found
        if np.mean(d > 0) >= 0.9:
            return found - 1 - target[seg], found
    return None, first_found


def rows_from_ring_field(points: np.ndarray, ring: np.ndarray, n_rings: int) -> np.ndarray:
    """(N,) int16 rows from a source's ring numbers, flipped when its ring 0 is the bottom beam.

    Vendors differ (Velodyne drivers: ring 0 = lowest beam; Ouster: ring 0 = top), so the
    direction is taken from the median elevation per ring.
    """
    r = np.asarray(ring).astype(np.int64)
    if len(r) == 0:
        return r.astype(np.int16)
    present = np.flatnonzero(np.bincount(r, minlength=n_rings))
    if len(present) >= 2:
        med = segment_medians(_elevation(points), r, int(r.max()) + 1)[present]
        if np.corrcoef(present, med)[0, 1] > 0:  # elevation rises with the ring number
            r = n_rings - 1 - r
    return np.clip(r, 0, n_rings - 1).astype(np.int16)


def _origin_heights(rho: np.ndarray, z: np.ndarray, ring: np.ndarray, n_rows: int) -> np.ndarray:
    """(R,) laser origin height per row: robust fit z = h + rho t; ill-posed rows borrow h."""
    h = np.zeros(n_rows)
    good = np.zeros(n_rows, dtype=bool)
    for r in range(n_rows):  # loop over rows, vectorised within
        m = ring == r
        if m.sum() < 50:
            continue
        rr, zz = rho[m], z[m]
        q10, q90 = np.percentile(rr, [10, 90])
        if q10 <= 0 or q90 / q10 < 2.0:  # too little range spread: h and t are confounded
            continue
        a = np.column_stack([np.ones_like(rr), rr])
        keep = np.ones(len(rr), dtype=bool)
        for _ in range(4):
            sol = np.linalg.lstsq(a[keep], zz[keep], rcond=None)[0]
            res = np.abs(zz - a @ sol)
            keep = res <= 2.5 * np.median(res[keep]) + 1e-4
        h[r], good[r] = sol[0], True
    gi = np.flatnonzero(good)
    if len(gi) == 0:
        return h
    for r in np.flatnonzero(~good):
        near = gi[np.argsort(np.abs(gi - r), kind="stable")[:4]]
        h[r] = np.median(h[near])
    return h


def check_rings(points: np.ndarray, ring: np.ndarray, n_rings: int, sectors: int = 72) -> RingCheck:
    """Measure how well `ring` (N,) rows match lasers; see the module docstring.

    Per row and azimuth sector (360/sectors degrees) the median of the origin-corrected elevation
    is the row's local elevation; a point is wrong when it lies beyond half the gap to the
    neighbouring row's local elevation, on that neighbour's side. Local sectors absorb the
    azimuth-dependent residue of motion compensation; the origin fit removes range parallax.
    """
    p = points.astype(np.float64)
    r = np.asarray(ring).astype(np.int64)
    assert p.ndim == 2 and p.shape[1] == 3 and r.shape == (len(p),)
    rho = np.hypot(p[:, 0], p[:, 1])
    h = _origin_heights(rho, p[:, 2], r, n_rings)
    el = np.degrees(np.arctan2(p[:, 2] - h[r], rho))
    sec = np.minimum((_azimuth(p) / TWO_PI * sectors).astype(np.int64), sectors - 1)
    row_med = segment_medians(el, r, n_rings)
    med = segment_medians(el, r * sectors + sec, n_rings * sectors).reshape(n_rings, sectors)
    med = np.where(np.isnan(med), row_med[:, None], med)
    own = med[r, sec]
    up = np.where(r > 0, med[np.maximum(r - 1, 0), sec] - own, np.nan)  # gap to the row above
    down = np.where(r < n_rings - 1, own - med[np.minimum(r + 1, n_rings - 1), sec], np.nan)
    up = np.where(np.isnan(up), down, up)  # edge rows: use the gap on the other side
    down = np.where(np.isnan(down), up, down)
    dev = el - own
    wrong = np.where(dev > 0, dev > 0.5 * up, -dev > 0.5 * down)
    wrong &= ~np.isnan(own)
    present = row_med[~np.isnan(row_med)]
    return RingCheck(
        rows=len(present),
        row_elevation=row_med,
        origin_height=h,
        monotonic=bool(np.all(np.diff(present) < 0)),
        wrong=wrong,
        wrong_fraction=float(wrong.mean()) if len(wrong) else 0.0,
    )
