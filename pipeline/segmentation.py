"""Region growing over 4-connected non-ground range-image pixels.

Two neighbours join when their range difference is under a threshold that grows with range
(separate vertical and horizontal thresholds); optionally they must also pass depth_clustering's
angle criterion. Columns wrap around at W-1 -> 0. With `bridge_empty`, a neighbour that holds no
return at all (a dropout on glass or dark paint) is stepped over to the next pixel in the same
direction; ground and other objects are never stepped over. Joins are decided
once per pixel pair (columns in parallel), then union-find over row runs labels the components; all in numba.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit, prange

from pipeline.config import SegmentationConfig
from pipeline.range_image import RangeImage
from pipeline.sensors import SensorModel


@dataclass(frozen=True)
class Segmentation:
    """pixel: (H, W) int32 segment id per pixel, -1 = none; point: (N,) int32 per point, -1 = none;
    count: number of segments (ids are 0..count-1)."""

    pixel: np.ndarray
    point: np.ndarray
    count: int


@njit(cache=True, inline="always")
def _thin_meets_wide(run_w, thin_below, tr, tc, wr, wc, thin_w, thin_h, wide_w, wide_ratio):  # pragma: no cover
    """Pixel (tr, tc) lies on a thin vertical structure and pixel (wr, wc) on a wide row run."""
    wt = run_w[tr, tc]
    return wt < thin_w and thin_below[tr, tc] >= thin_h and run_w[wr, wc] >= max(wide_w, wide_ratio * wt)


@njit(cache=True, inline="always")
def _angle_cuts(dmin, dmax, sin_a, cos_a, tan_beta):  # pragma: no cover - numba
    """depth_clustering's criterion fails: beta = atan2(d2 sin a, d1 - d2 cos a) under the threshold."""
    den = dmax - dmin * cos_a
    return den > 0.0 and dmin * sin_a < tan_beta * den


@njit(cache=True, parallel=True)
def _join_edges(rng, ok, empty, vb, vs, hb, hs, ob, os_, run_w, thin_below, thin_w, thin_h, wide_w, wide_ratio,
                use_angle, tan_beta, v_alpha, h_alpha, bridge):  # pragma: no cover - numba
    """Which neighbours join, decided once per pixel pair: right[r, c] and down[r, c] are 0 (no
    join) or the distance (1, or 2 when `bridge` stepped over an empty pixel) to the right-hand
    (column wraps at W-1 -> 0) and the lower neighbour that (r, c) joins. Every rule is symmetric,
    so these two (H, W) uint8 maps are the whole undirected 4-neighbour graph."""
    h, w = rng.shape
    right = np.zeros((h, w), dtype=np.uint8)
    down = np.zeros((h, w), dtype=np.uint8)
    thin = thin_w > 0.0
    over = os_ > 0.0
    sin_h = np.sin(h_alpha)
    cos_h = np.cos(h_alpha)
    for c in prange(w):  # columns in parallel: objects crowd some rows, azimuth halves are balanced
        for r in range(h):
            if not ok[r, c]:
                continue
            d1 = rng[r, c]
            # right-hand neighbour
            c1 = c + 1
            if c1 == w:
                c1 = 0
            step = 1
            while step <= bridge and empty[r, c1]:
                # no return at all here (glass, dark paint): look one pixel further
                c1 += 1
                if c1 == w:
                    c1 = 0
                step += 1
            if ok[r, c1]:
                d2 = rng[r, c1]
                dmin = min(d1, d2)
                dmax = max(d1, d2)
                join = dmax - dmin <= hb + hs * dmin
                if join and thin:
                    # a trunk seen through the holes of its crown: a thin pixel beside a wide run
                    join = not (
                        _thin_meets_wide(run_w, thin_below, r, c, r, c1, thin_w, thin_h, wide_w, wide_ratio)
                        or _thin_meets_wide(run_w, thin_below, r, c1, r, c, thin_w, thin_h, wide_w, wide_ratio)
                    )
                if join and use_angle and _angle_cuts(dmin, dmax, sin_h, cos_h, tan_beta):
                    join = False
                if join:
                    right[r, c] = step
            # lower neighbour: (r, c) is the upper pixel
            r1 = r + 1
            if r1 >= h:
                continue
            step = 1
            while step <= bridge and r1 < h - 1 and empty[r1, c]:
                r1 += 1
                step += 1
            if ok[r1, c]:
                d2 = rng[r1, c]
                dmin = min(d1, d2)
                dmax = max(d1, d2)
                join = dmax - dmin <= vb + vs * dmin
                if join and thin and d1 <= d2 + 0.1:
                    # a crown over a trunk: the lower pixel thin, the upper one wide and not behind
                    join = not _thin_meets_wide(run_w, thin_below, r1, c, r, c, thin_w, thin_h, wide_w, wide_ratio)
                if join and over and d2 - d1 > ob + os_ * dmax:
                    join = False  # the upper pixel nearer by more than the overhang allows
                if join and use_angle:
                    a = v_alpha[r] if r < h - 1 else v_alpha[h - 2]
                    join = not _angle_cuts(dmin, dmax, np.sin(a), np.cos(a), tan_beta)
                if join:
                    down[r, c] = step
    return right, down


@njit(cache=True, inline="always")
def _find(parent, p):  # pragma: no cover - numba
    """Root of `p` in the union-find forest `parent` (path halving)."""
    while parent[p] != p:
        parent[p] = parent[parent[p]]
        p = parent[p]
    return p


@njit(cache=True, inline="always")
def _union(parent, a, b):  # pragma: no cover - numba
    ra = _find(parent, a)
    rb = _find(parent, b)
    if ra < rb:
        parent[rb] = ra
    elif rb < ra:
        parent[ra] = rb


@njit(cache=True, parallel=True)
def _label_components(ok, right, down):  # pragma: no cover - numba
    """Connected components of the join graph: (H, W) int32 ids numbered in raster order of each
    component's first pixel (-1 = not ok), (count,) int32 pixel counts, count.

    1. Each row is cut into runs of right-joined pixels (a run stops at the seam W-1 -> 0); rows
       in parallel, then each row's runs get consecutive ids in raster order.
    2. Vertical joins, and right joins across the seam, merge runs in a union-find forest.
    3. Runs are numbered in raster order of their first pixel, so components are too.
    """
    h, w = ok.shape
    run_of = np.empty((h, w), dtype=np.int32)  # the run of each ok pixel, first as an id in its row
    row_len = np.empty((h, w), dtype=np.int32)  # pixel count of each row's k-th run
    row_runs = np.zeros(h, dtype=np.int32)
    for r in prange(h):
        n = 0
        c = 0
        while c < w:
            if not ok[r, c]:
                c += 1
                continue
            size = 1
            run_of[r, c] = n
            while True:
                d = right[r, c]
                if d == 0 or c + d >= w:
                    break
                c += d  # a bridged step skips an empty pixel, which belongs to no run
                run_of[r, c] = n
                size += 1
            row_len[r, n] = size
            n += 1
            c += 1
        row_runs[r] = n
    first = np.zeros(h + 1, dtype=np.int32)  # id of each row's first run
    for r in range(h):
        first[r + 1] = first[r] + row_runs[r]
    n = first[h]
    parent = np.arange(n, dtype=np.int32)
    length = np.empty(n, dtype=np.int32)
    for r in prange(h):
        for c in range(w):
            if ok[r, c]:
                run_of[r, c] += first[r]
        for k in range(row_runs[r]):
            length[first[r] + k] = row_len[r, k]
    for r in range(h - 1):
        last_a = -1
        last_b = -1
        for c in range(w):
            d = down[r, c]
            if d > 0:
                a = run_of[r, c]
                b = run_of[r + d, c]
                if a != last_a or b != last_b:  # neighbouring columns mostly join the same two runs
                    _union(parent, a, b)
                    last_a = a
                    last_b = b
    for r in range(h):
        d = right[r, w - 1]
        if d > 0:
            _union(parent, run_of[r, w - 1], run_of[r, d - 1])
        if w >= 2 and right[r, w - 2] == 2:
            _union(parent, run_of[r, w - 2], run_of[r, 0])
    lab = np.full(n, -1, dtype=np.int32)
    sizes = np.zeros(n, dtype=np.int32)
    nxt = 0
    for k in range(n):
        root = _find(parent, k)
        if lab[root] < 0:
            lab[root] = nxt
            nxt += 1
        lab[k] = lab[root]
        sizes[lab[k]] += length[k]
    labels = np.full((h, w), -1, dtype=np.int32)
    for r in prange(h):
        for c in range(w):
            if ok[r, c]:
                labels[r, c] = lab[run_of[r, c]]
    return labels, sizes[:nxt], nxt


@njit(cache=True, parallel=True)
def _row_runs(rng, ok, hb, hs, col_angle, max_gap):  # pragma: no cover - numba
    """(H, W) float32 width in metres of the row run each ok pixel belongs to (0 elsewhere).

    A row run chains ok pixels left to right whose range stays within the horizontal threshold of
    the run's previous pixel, stepping over up to `max_gap` other pixels (holes of a porous crown,
    noisy returns, dropouts). Its width is its column span times the mean range times the column
    angle. Runs cannot cross a longer gap, so rows are scanned from one (labels stay invariant to
    column rotation).
    """
    h, w = rng.shape
    run_w = np.zeros((h, w), dtype=np.float32)
    half = (h + 1) // 2
    for kk in prange(h):
        # even rows first, then odd ones: each thread gets rows from top to bottom (objects crowd
        # some rows, so contiguous blocks of rows would leave one thread idle)
        r = 2 * kk if kk < half else 2 * (kk - half) + 1
        members = np.empty(w, dtype=np.int32)
        done = np.zeros(w, dtype=np.bool_)
        # start right after a stretch of more than max_gap non-ok pixels
        start = 0
        gap = 0
        found = False
        for k in range(2 * w):
            c = k if k < w else k - w  # (k mod w without an integer division)
            if ok[r, c]:
                if gap > max_gap:
                    start = c
                    found = True
                    break
                gap = 0
            else:
                gap += 1
                if gap > w:
                    break
        if not found:
            if gap > w:
                continue  # no ok pixel in the row
            start = 0  # no long gap anywhere: the row is nearly full, the seam is as good as any
        for k in range(w):
            c0 = start + k
            if c0 >= w:
                c0 -= w
            if not ok[r, c0] or done[c0]:
                continue
            n = 0
            members[n] = c0
            n += 1
            done[c0] = True
            total = rng[r, c0]
            last_k = k
            last_d = rng[r, c0]
            j = k + 1
            while j < w and j - last_k - 1 <= max_gap:
                cj = start + j
                if cj >= w:
                    cj -= w
                if ok[r, cj] and not done[cj]:
                    d = rng[r, cj]
                    if abs(d - last_d) <= hb + hs * min(d, last_d):
                        members[n] = cj
                        n += 1
                        done[cj] = True
                        total += d
                        last_k = j
                        last_d = d
                j += 1
            width = np.float32((last_k - k + 1) * col_angle * total / n)
            for m in range(n):
                run_w[r, members[m]] = width
    return run_w


@njit(cache=True, parallel=True)
def _thin_heights(rng, ok, run_w, vb, vs, thin_w, v_alpha):  # pragma: no cover - numba
    """(H, W) float32 metres of the thin vertical structure from each pixel down (a pixel is thin
    when its row run is narrower than `thin_w`; the chain follows the vertical criterion)."""
    h, w = rng.shape
    below = np.zeros((h, w), dtype=np.float32)
    for c in prange(w):
        for r in range(h - 1, -1, -1):
            if not ok[r, c] or run_w[r, c] >= thin_w:
                continue
            own = v_alpha[min(r, h - 2)] * rng[r, c]
            if r + 1 < h and below[r + 1, c] > 0.0:
                d1 = rng[r, c]
                d2 = rng[r + 1, c]
                if abs(d1 - d2) <= vb + vs * min(d1, d2):
                    own += below[r + 1, c]
            below[r, c] = own
    return below


@njit(cache=True, parallel=True)
def _finish(labels, sizes, count, min_points, row, col, point_range, pix_range, kept, ground, hb, hs):  # pragma: no cover
    """Drop segments under `min_points` pixels, renumber densely, and label every point whose
    range agrees with its pixel's nearest point (within the horizontal threshold)."""
    h, w = labels.shape
    remap = np.full(count, -1, dtype=np.int32)
    nxt = 0
    for k in range(count):
        if sizes[k] >= min_points:
            remap[k] = nxt
            nxt += 1
    pixel = labels  # relabelled in place
    for r in prange(h):
        for c in range(w):
            if labels[r, c] >= 0:
                pixel[r, c] = remap[labels[r, c]]
    n = row.shape[0]
    point = np.full(n, -1, dtype=np.int32)
    for i in prange(n):
        if not kept[i] or ground[i]:
            continue
        seg = pixel[row[i], col[i]]
        if seg < 0:
            continue
        pr = pix_range[row[i], col[i]]
        if abs(point_range[i] - pr) <= hb + hs * pr:
            point[i] = seg
    return pixel, point, nxt


@njit(cache=True, parallel=True)
def _segment_kernel(
    index, rng, ground, row, col, point_range, kept, vb, vs, hb, hs, ob, os_, thin_w, thin_h, wide_w, wide_ratio,
    use_angle, tan_beta, v_alpha, col_angle, bridge, min_points,
):  # pragma: no cover - numba
    """Masks, row runs, growth and point labels in one call (no Python between the passes)."""
    h, w = index.shape
    ok = np.zeros((h, w), dtype=np.bool_)
    empty = np.zeros((h, w), dtype=np.bool_)
    for r in prange(h):
        for c in range(w):
            i = index[r, c]
            if i < 0:
                empty[r, c] = True
            elif not ground[i]:
                ok[r, c] = True
    if thin_w > 0.0:
        run_w = _row_runs(rng, ok, hb, hs, col_angle, 3)
        thin_below = _thin_heights(rng, ok, run_w, vb, vs, thin_w, v_alpha)
    else:
        run_w = np.zeros((1, 1), dtype=np.float32)
        thin_below = run_w
    right, down = _join_edges(
        rng, ok, empty, vb, vs, hb, hs, ob, os_, run_w, thin_below, thin_w, thin_h, wide_w, wide_ratio, use_angle,
        tan_beta, v_alpha, col_angle, bridge,
    )
    labels, sizes, count = _label_components(ok, right, down)
    return _finish(labels, sizes, count, min_points, row, col, point_range, rng, kept, ground, hb, hs)


def segment(
    image: RangeImage,
    ground: np.ndarray,
    sensor: SensorModel,
    config: SegmentationConfig | None = None,
) -> Segmentation:
    """Segment the non-ground pixels of `image`; `ground` is the (N,) per-point ground mask."""
    config = config or SegmentationConfig()
    h, w = image.shape
    pixel, point, count = _segment_kernel(
        image.index, image.range, ground, image.row, image.col, image.point_range, image.kept,
        float(config.vertical_base), float(config.vertical_slope), float(config.horizontal_base),
        float(config.horizontal_slope), float(config.overhang_base), float(config.overhang_slope),
        np.float32(config.thin_width), np.float32(config.thin_min_height), np.float32(config.wide_width),
        np.float32(config.wide_ratio), bool(config.use_angle_criterion),
        float(np.tan(np.deg2rad(config.angle_threshold_deg))), _beam_steps(sensor, h),
        np.float32(2.0 * np.pi / w), int(config.bridge_pixels) if config.bridge_empty else 0, max(1, config.min_points),
    )
    return Segmentation(pixel=pixel, point=point, count=int(count))


_BEAM_STEPS: dict[tuple, np.ndarray] = {}


def _beam_steps(sensor: SensorModel, h: int) -> np.ndarray:
    """(H - 1,) float32 elevation step (rad) between consecutive beams, cached per sensor."""
    key = (sensor.elevations_deg, h)
    out = _BEAM_STEPS.get(key)
    if out is None:
        el = sensor.elevations_rad()
        steps = np.abs(np.diff(el)) if len(el) == h else np.full(h - 1, np.deg2rad(1.0))
        out = _BEAM_STEPS[key] = np.ascontiguousarray(steps, dtype=np.float32)
    return out
