"""Region growing over 4-connected non-ground range-image pixels.

Two neighbours join when their range difference is under a threshold that grows with range
(separate vertical and horizontal thresholds); optionally they must also pass depth_clustering's
angle criterion. Columns wrap around at W-1 -> 0. With `bridge_empty`, a neighbour that holds no
return at all (a dropout on glass or dark paint) is stepped over to the next pixel in the same
direction; ground and other objects are never stepped over. The flood fill runs in numba.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

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


@njit(cache=True)
def _thin_meets_wide(run_w, thin_below, tr, tc, wr, wc, thin_w, thin_h, wide_w, wide_ratio):  # pragma: no cover
    """Pixel (tr, tc) lies on a thin vertical structure and pixel (wr, wc) on a wide row run."""
    wt = run_w[tr, tc]
    return wt < thin_w and thin_below[tr, tc] >= thin_h and run_w[wr, wc] >= max(wide_w, wide_ratio * wt)


@njit(cache=True)
def _grow(rng, ok, empty, vb, vs, hb, hs, ob, os_, run_w, thin_below, thin_w, thin_h, wide_w, wide_ratio, use_angle,
          tan_beta, v_alpha, h_alpha, bridge):  # pragma: no cover
    h, w = rng.shape
    labels = np.full((h, w), -1, dtype=np.int32)
    sizes = np.zeros(h * w, dtype=np.int32)
    stack_r = np.empty(h * w, dtype=np.int32)
    stack_c = np.empty(h * w, dtype=np.int32)
    nxt = 0
    for r0 in range(h):
        for c0 in range(w):
            if not ok[r0, c0] or labels[r0, c0] >= 0:
                continue
            labels[r0, c0] = nxt
            top = 0
            stack_r[0] = r0
            stack_c[0] = c0
            top = 1
            size = 1
            while top > 0:
                top -= 1
                r = stack_r[top]
                c = stack_c[top]
                d1 = rng[r, c]
                for k in range(4):
                    if k == 0:
                        dr, dc, vert = -1, 0, True
                    elif k == 1:
                        dr, dc, vert = 1, 0, True
                    elif k == 2:
                        dr, dc, vert = 0, -1, False
                    else:
                        dr, dc, vert = 0, 1, False
                    nr = r + dr
                    nc = (c + dc) % w
                    if nr < 0 or nr >= h:
                        continue
                    if bridge and empty[nr, nc]:
                        # no return at all here (glass, dark paint): look one pixel further
                        nr = nr + dr
                        nc = (nc + dc) % w
                        if nr < 0 or nr >= h:
                            continue
                    if not ok[nr, nc] or labels[nr, nc] >= 0:
                        continue
                    d2 = rng[nr, nc]
                    dmin = min(d1, d2)
                    dmax = max(d1, d2)
                    if vert:
                        thr = vb + vs * dmin
                    else:
                        thr = hb + hs * dmin
                    if dmax - dmin > thr:
                        continue
                    if thin_w > 0.0:
                        if vert:
                            # a crown over a trunk: the lower pixel thin, the upper one wide and not behind
                            lr, lc, ur, uc = (nr, nc, r, c) if nr > r else (r, c, nr, nc)
                            cut = rng[ur, uc] <= rng[lr, lc] + 0.1 and _thin_meets_wide(
                                run_w, thin_below, lr, lc, ur, uc, thin_w, thin_h, wide_w, wide_ratio
                            )
                        else:
                            # a trunk seen through the holes of its crown: a thin pixel beside a wide run
                            cut = _thin_meets_wide(
                                run_w, thin_below, r, c, nr, nc, thin_w, thin_h, wide_w, wide_ratio
                            ) or _thin_meets_wide(run_w, thin_below, nr, nc, r, c, thin_w, thin_h, wide_w, wide_ratio)
                        if cut:
                            continue
                    if vert and os_ > 0.0:
                        # range of the upper pixel minus that of the lower one
                        up_minus_low = (d1 - d2) if nr > r else (d2 - d1)
                        if up_minus_low < 0.0 and -up_minus_low > ob + os_ * dmax:
                            continue
                    if use_angle:
                        a = v_alpha[min(min(r, nr), h - 2)] if vert else h_alpha
                        # depth_clustering: beta = atan2(d2 sin a, d1 - d2 cos a) > threshold
                        num = dmin * np.sin(a)
                        den = dmax - dmin * np.cos(a)
                        if den > 0.0 and num < tan_beta * den:
                            continue
                    labels[nr, nc] = nxt
                    size += 1
                    stack_r[top] = nr
                    stack_c[top] = nc
                    top += 1
            sizes[nxt] = size
            nxt += 1
    return labels, sizes[:nxt], nxt


@njit(cache=True)
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
    members = np.empty(w, dtype=np.int32)
    done = np.zeros(w, dtype=np.bool_)
    for r in range(h):
        # start right after a stretch of more than max_gap non-ok pixels
        start = 0
        gap = 0
        found = False
        for k in range(2 * w):
            c = k % w
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
        done[:] = False
        for k in range(w):
            c0 = (start + k) % w
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
                cj = (start + j) % w
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


@njit(cache=True)
def _thin_heights(rng, ok, run_w, vb, vs, thin_w, v_alpha):  # pragma: no cover - numba
    """(H, W) float32 metres of the thin vertical structure from each pixel down (a pixel is thin
    when its row run is narrower than `thin_w`; the chain follows the vertical criterion)."""
    h, w = rng.shape
    below = np.zeros((h, w), dtype=np.float32)
    for c in range(w):
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


@njit(cache=True)
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
    for r in range(h):
        for c in range(w):
            if labels[r, c] >= 0:
                pixel[r, c] = remap[labels[r, c]]
    n = row.shape[0]
    point = np.full(n, -1, dtype=np.int32)
    for i in range(n):
        if not kept[i] or ground[i]:
            continue
        seg = pixel[row[i], col[i]]
        if seg < 0:
            continue
        pr = pix_range[row[i], col[i]]
        if abs(point_range[i] - pr) <= hb + hs * pr:
            point[i] = seg
    return pixel, point, nxt


@njit(cache=True)
def _segment_kernel(
    index, rng, ground, row, col, point_range, kept, vb, vs, hb, hs, ob, os_, thin_w, thin_h, wide_w, wide_ratio,
    use_angle, tan_beta, v_alpha, col_angle, bridge, min_points,
):  # pragma: no cover - numba
    """Masks, row runs, growth and point labels in one call (no Python between the passes)."""
    h, w = index.shape
    ok = np.zeros((h, w), dtype=np.bool_)
    empty = np.zeros((h, w), dtype=np.bool_)
    for r in range(h):
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
    labels, sizes, count = _grow(
        rng, ok, empty, vb, vs, hb, hs, ob, os_, run_w, thin_below, thin_w, thin_h, wide_w, wide_ratio, use_angle,
        tan_beta, v_alpha, col_angle, bridge,
    )
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
        np.float32(2.0 * np.pi / w), bool(config.bridge_empty), max(1, config.min_points),
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
