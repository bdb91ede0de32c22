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


@dataclass(frozen=True)
class GroundResult:
    """ground: (N,) bool per point; height: (N,) float32 metres above the ground surface;
    sensor_height: metres of the sensor above the ground under it."""

    ground: np.ndarray
    height: np.ndarray
    sensor_height: float


@njit(cache=True, parallel=True)
def _column_walk(index, points, tan_slope, tan_start, tol, sensor_height, max_run):  # pragma: no cover - numba
    h, w = index.shape
    out = np.zeros(points.shape[0], dtype=np.bool_)
    for c in prange(w):  # columns in parallel; each point owns at most one pixel
        last_xy = 0.0
        last_z = -sensor_height
        first = True
        for r in range(h - 1, -1, -1):
            i = index[r, c]
            if i < 0:
                continue
            xy_i = np.sqrt(points[i, 0] * points[i, 0] + points[i, 1] * points[i, 1])
            z_i = points[i, 2]
            dxy = xy_i - last_xy
            dz = abs(z_i - last_z)
            lim = tan_start if first else tan_slope
            # a slope may not accumulate over a long gap without returns (a far car behind an
            # empty stretch would otherwise look like rising ground)
            run = dxy if first else min(dxy, max_run)
            if dxy > 0.0 and dz <= lim * run + tol:
                out[i] = True
                last_xy = xy_i
                last_z = z_i
                first = False
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


@njit(cache=True, parallel=True)
def _surface_and_band(points, walk, kept, sensor_h, cell, band):  # pragma: no cover - numba
    """Ground surface on a `cell` grid (trimmed mean z of the walk's ground points per cell, empty
    cells filled from the nearest filled cell, bilinear lookup): (N,) ground mask with the band
    added and (N,) float32 height above the surface."""
    n = points.shape[0]
    height = np.empty(n, dtype=np.float32)
    ground = np.empty(n, dtype=np.bool_)
    n_ground = 0
    for i in prange(n):
        n_ground += 1 if walk[i] else 0
    if n_ground < 3:
        for i in prange(n):
            height[i] = points[i, 2] + sensor_h
            ground[i] = (walk[i] or abs(height[i]) <= band) and kept[i]
        return ground, height
    lo0 = np.inf
    lo1 = np.inf
    hi0 = -np.inf
    hi1 = -np.inf
    for i in range(n):  # the grid spans the ground points (pixels, so within max_range)
        if walk[i]:
            lo0 = min(lo0, points[i, 0])
            lo1 = min(lo1, points[i, 1])
            hi0 = max(hi0, points[i, 0])
            hi1 = max(hi1, points[i, 1])
    lo0 = lo0 - cell
    lo1 = lo1 - cell
    inv = 1.0 / cell
    g0 = int((hi0 - lo0) * inv) + 3
    g1 = int((hi1 - lo1) * inv) + 3
    # the walk's ground points with their cell (computed once)
    gi = np.empty(n_ground, dtype=np.int32)
    gz = np.empty(n_ground, dtype=np.float32)
    k = 0
    for i in range(n):
        if walk[i]:
            gi[k] = int((points[i, 0] - lo0) * inv) * g1 + int((points[i, 1] - lo1) * inv)
            gz[k] = points[i, 2]
            k += 1
    sums = np.zeros(g0 * g1)
    counts = np.zeros(g0 * g1, dtype=np.int32)
    for k in range(n_ground):
        sums[gi[k]] += gz[k]
        counts[gi[k]] += 1
    # second pass: trimmed mean without points well above the first mean (feet of objects)
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
    # fill empty cells from the nearest filled one (breadth-first over 8-neighbours), on a grid
    # padded by one cell that counts as filled, so the neighbours need no bounds checks
    p1 = g1 + 2
    padded = np.zeros((g0 + 2) * p1)
    filled = np.ones((g0 + 2) * p1, dtype=np.bool_)
    queue = np.empty(g0 * g1, dtype=np.int64)
    head = 0
    tail = 0
    for a in range(g0):
        for b in range(g1):
            q = (a + 1) * p1 + b + 1
            cell_q = a * g1 + b
            filled[q] = counts2[cell_q] > 0
            if filled[q]:
                padded[q] = sums2[cell_q] / counts2[cell_q]
                queue[tail] = q
                tail += 1
    offsets = np.array([-p1 - 1, -p1, -p1 + 1, -1, 1, p1 - 1, p1, p1 + 1], dtype=np.int64)
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
    grid = padded.reshape(g0 + 2, p1)[1 : g0 + 1, 1 : g1 + 1]
    for i in prange(n):
        # clamped to the grid: a point beyond it (off the ground points' extent) takes the height
        # above the nearest edge; clamping before int() also keeps 1e9 m points in range
        u = min(max((points[i, 0] - lo0) * inv - 0.5, 0.0), g0 - 1.0)
        v = min(max((points[i, 1] - lo1) * inv - 0.5, 0.0), g1 - 1.0)
        a = min(int(u), g0 - 2)
        b = min(int(v), g1 - 2)
        fu = u - a
        fv = v - b
        z0 = grid[a, b] + (grid[a, b + 1] - grid[a, b]) * fv
        z1 = grid[a + 1, b] + (grid[a + 1, b + 1] - grid[a + 1, b]) * fv
        hgt = np.float32(points[i, 2] - (z0 + (z1 - z0) * fu))
        height[i] = hgt
        ground[i] = (walk[i] or abs(hgt) <= band) and kept[i]
    return ground, height
