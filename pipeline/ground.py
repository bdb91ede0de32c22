"""Ground removal and height above ground.

1. Angle-based labelling along each range-image column (as in depth_clustering): walking up
   from the bottom beam, a point is ground while the slope from the last ground point stays under
   `max_slope_deg` (the first one is compared with the ground under the sensor).
2. A ground surface on a `grid_cell` grid (mean z of ground points per cell, empty cells filled
   from the nearest filled cell by an 8-neighbour breadth-first fill, bilinear lookup) gives every point its height above ground.
   The grid spans the walk's ground points only (pixels of the range image, so within
   `max_range`): its memory is bounded by the range, never by a stray point at 1e9 m, which takes
   the height above the surface's nearest edge.
3. Non-ground points within `ground_band` of that surface are ground too (curbs, low grass).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit, prange

from pipeline.config import GroundConfig
from pipeline.range_image import RangeImage
from pipeline.scan import Scan

# LLVM's fast-math without "no NaN / no inf": a point of 1e38 m may overflow to inf in a product,
# which the full fast-math would treat as undefined.
FAST_MATH = {"nsz", "arcp", "contract", "afn", "reassoc"}
FIRST_RUN = 6.0  # metres, see `_column_walk`


@dataclass(frozen=True)
class GroundResult:
    """ground: (N,) bool per point; height: (N,) float32 metres above the ground surface;
    sensor_height: metres of the sensor above the ground under it."""

    ground: np.ndarray
    height: np.ndarray
    sensor_height: float


@njit(cache=True, fastmath=FAST_MATH)
def _column_walk(index, points, tan_slope, tan_start, tol, sensor_height, max_run):  # pragma: no cover - numba
    """(N,) bool: the ground points of step 1, every column walked up from its bottom beam.

    All columns advance one row at a time (each keeps its last ground point), so the row-major
    image and the scan-ordered points are read in memory order: 2.5x faster than walking one
    column at a time. float32 like the points."""
    h, w = index.shape
    out = np.zeros(points.shape[0], dtype=np.bool_)
    slope = np.float32(tan_slope)
    tol32 = np.float32(tol)
    last_xy = np.zeros(w, dtype=np.float32)
    last_z = np.full(w, -sensor_height, dtype=np.float32)
    lim = np.full(w, tan_start, dtype=np.float32)
    # a slope may not accumulate over a long gap without returns (a far car behind an empty
    # stretch would otherwise look like rising ground); before a column's first ground point it
    # counts over at most FIRST_RUN m from the sensor's foot (a lone return 3 m above the road,
    # 12 m away, is no ground)
    cap = np.full(w, FIRST_RUN, dtype=np.float32)
    for r in range(h - 1, -1, -1):
        for c in range(w):
            i = index[r, c]
            if i < 0:
                continue
            x = points[i, 0]
            y = points[i, 1]
            xy_i = np.sqrt(x * x + y * y)
            z_i = points[i, 2]
            dxy = xy_i - last_xy[c]
            run = min(dxy, cap[c])
            if dxy > 0.0 and abs(z_i - last_z[c]) <= lim[c] * run + tol32:
                out[i] = True
                last_xy[c] = xy_i
                last_z[c] = z_i
                lim[c] = slope
                cap[c] = max_run
    return out


@njit(cache=True)
def _sensor_height_kernel(index, points, first_row):  # pragma: no cover - numba
    h, w = index.shape
    buf = np.empty((h - first_row) * w, dtype=np.float32)
    n = 0
    for r in range(first_row, h):
        for c in range(w):
            i = index[r, c]
            if i >= 0:
                xy2 = points[i, 0] * points[i, 0] + points[i, 1] * points[i, 1]
                if 4.0 < xy2 < 225.0:
                    buf[n] = points[i, 2]
                    n += 1
    if n < 20:
        return 1.8
    return -np.percentile(buf[:n], 30.0)


def estimate_sensor_height(scan: Scan, image: RangeImage) -> float:
    """Sensor height (m) from the lowest beams' points 2–15 m away (robust low percentile)."""
    h = image.shape[0]
    return float(_sensor_height_kernel(image.index, scan.points, h - max(2, h // 8)))


def estimate_ground(scan: Scan, image: RangeImage, config: GroundConfig | None = None) -> GroundResult:
    """Ground mask and height above ground for every point of `scan`."""
    config = config or GroundConfig()
    n = len(scan)
    if n == 0:
        return GroundResult(np.zeros(0, bool), np.zeros(0, np.float32), config.sensor_height or 1.8)
    pts = scan.points
    sensor_h = config.sensor_height if config.sensor_height is not None else estimate_sensor_height(scan, image)
    walk = _column_walk(
        image.index,
        pts,
        np.tan(np.deg2rad(config.max_slope_deg)),
        np.tan(np.deg2rad(config.start_angle_deg)),
        0.05,
        sensor_h,
        config.max_run,
    )
    ground, height = _surface_and_band(pts, walk, image.kept, sensor_h, config.grid_cell, config.ground_band)
    return GroundResult(ground=ground, height=height, sensor_height=float(sensor_h))


@njit(cache=True, fastmath=FAST_MATH)
def _surface_and_band(points, walk, kept, sensor_h, cell, band):  # pragma: no cover - numba
    """Ground surface on a `cell` grid (trimmed mean z of the walk's ground points per cell, empty
    cells filled from the nearest filled cell, bilinear lookup): (N,) ground mask with the band
    added and (N,) float32 height above the surface."""
    n = points.shape[0]
    n_ground = 0
    lo0 = lo1 = np.inf
    hi0 = hi1 = -np.inf
    for i in range(n):  # the grid spans the ground points (pixels, so within max_range)
        if walk[i]:
            n_ground += 1
            lo0 = min(lo0, points[i, 0])
            lo1 = min(lo1, points[i, 1])
            hi0 = max(hi0, points[i, 0])
            hi1 = max(hi1, points[i, 1])
    if n_ground < 3:  # a flat surface at the sensor's foot
        return _bilinear_lookup(points, walk, kept, np.full((2, 2), -sensor_h, np.float32), 0.0, 0.0, 1.0, band)
    lo0 -= cell
    lo1 -= cell
    inv = 1.0 / cell
    grid = _ground_grid(points, walk, n_ground, lo0, lo1, inv, int((hi0 - lo0) * inv) + 3, int((hi1 - lo1) * inv) + 3)
    return _bilinear_lookup(points, walk, kept, grid, lo0, lo1, inv, band)


@njit(cache=True)
def _ground_grid(points, walk, n_ground, lo0, lo1, inv, g0, g1):  # pragma: no cover - numba
    """(g0, g1) float32 ground height per cell: the mean z of the ground points in the cell
    without those well above the first mean (feet of objects); empty cells take the value of the
    nearest filled cell (breadth-first over 8-neighbours)."""
    gi = np.empty(n_ground, dtype=np.int32)  # the ground points' cells, computed once
    gz = np.empty(n_ground, dtype=np.float32)
    k = 0
    for i in range(points.shape[0]):
        if walk[i]:
            gi[k] = int((points[i, 0] - lo0) * inv) * g1 + int((points[i, 1] - lo1) * inv)
            gz[k] = points[i, 2]
            k += 1
    sums = np.zeros(g0 * g1)
    counts = np.zeros(g0 * g1, dtype=np.int32)
    for k in range(n_ground):
        sums[gi[k]] += gz[k]
        counts[gi[k]] += 1
    for q in range(g0 * g1):
        if counts[q] > 0:
            sums[q] /= counts[q]
    sums2 = np.zeros(g0 * g1)
    counts2 = np.zeros(g0 * g1, dtype=np.int32)
    for k in range(n_ground):
        q = gi[k]
        if gz[k] <= sums[q] + 0.05:
            sums2[q] += gz[k]
            counts2[q] += 1
    # the fill runs on a grid padded by one cell that counts as filled, so the neighbours need
    # no bounds checks
    p1 = g1 + 2
    padded = np.zeros((g0 + 2) * p1, dtype=np.float32)
    filled = np.ones((g0 + 2) * p1, dtype=np.bool_)
    queue = np.empty(g0 * g1, dtype=np.int64)
    tail = 0
    for a in range(g0):
        for b in range(g1):
            q = (a + 1) * p1 + b + 1
            filled[q] = counts2[a * g1 + b] > 0
            if filled[q]:
                padded[q] = sums2[a * g1 + b] / counts2[a * g1 + b]
                queue[tail] = q
                tail += 1
    offsets = np.array([-p1 - 1, -p1, -p1 + 1, -1, 1, p1 - 1, p1, p1 + 1], dtype=np.int64)
    head = 0
    while head < tail:
        q = queue[head]
        head += 1
        for k in range(8):
            nq = q + offsets[k]
            if not filled[nq]:
                filled[nq] = True
                padded[nq] = padded[q]
                queue[tail] = nq
                tail += 1
    return padded.reshape(g0 + 2, p1)[1 : g0 + 1, 1 : g1 + 1]


@njit(cache=True, parallel=True, fastmath=FAST_MATH)
def _bilinear_lookup(points, walk, kept, grid, lo0, lo1, inv, band):  # pragma: no cover - numba
    """(N,) ground mask (the walk's, plus the band around the surface) and (N,) float32 height
    above the bilinear surface through the cell centres of `grid` (corner at lo0, lo1).

    Each cell's bilinear patch is stored as four coefficients side by side, so a point reads one
    cache line instead of four scattered grid values. A point beyond the grid (off the ground
    points' extent) takes the height above the nearest edge; clamping before int() also keeps
    1e9 m points in range."""
    g0, g1 = grid.shape
    co = np.empty((g0 - 1, g1 - 1, 4), dtype=np.float32)
    for a in range(g0 - 1):
        for b in range(g1 - 1):
            co[a, b, 0] = grid[a, b]
            co[a, b, 1] = grid[a + 1, b] - grid[a, b]
            co[a, b, 2] = grid[a, b + 1] - grid[a, b]
            co[a, b, 3] = grid[a + 1, b + 1] - grid[a + 1, b] - grid[a, b + 1] + grid[a, b]
    off0 = np.float32(lo0 * inv + 0.5)
    off1 = np.float32(lo1 * inv + 0.5)
    inv32 = np.float32(inv)
    top0 = np.float32(g0 - 1.0)
    top1 = np.float32(g1 - 1.0)
    band32 = np.float32(band)
    n = points.shape[0]
    height = np.empty(n, dtype=np.float32)
    ground = np.empty(n, dtype=np.bool_)
    for i in prange(n):
        u = min(max(points[i, 0] * inv32 - off0, np.float32(0.0)), top0)
        v = min(max(points[i, 1] * inv32 - off1, np.float32(0.0)), top1)
        a = min(int(u), g0 - 2)
        b = min(int(v), g1 - 2)
        fu = u - a
        fv = v - b
        hgt = points[i, 2] - (co[a, b, 0] + co[a, b, 1] * fu + (co[a, b, 2] + co[a, b, 3] * fu) * fv)
        height[i] = hgt
        ground[i] = (walk[i] or abs(hgt) <= band32) and kept[i]
    return ground, height
