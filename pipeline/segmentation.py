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
def _grow(rng, ok, empty, vb, vs, hb, hs, use_angle, tan_beta, v_alpha, h_alpha, bridge):  # pragma: no cover
    h, w = rng.shape
    labels = np.full((h, w), -1, dtype=np.int32)
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
                    if use_angle:
                        a = v_alpha[min(min(r, nr), h - 2)] if vert else h_alpha
                        # depth_clustering: beta = atan2(d2 sin a, d1 - d2 cos a) > threshold
                        num = dmin * np.sin(a)
                        den = dmax - dmin * np.cos(a)
                        if den > 0.0 and num < tan_beta * den:
                            continue
                    labels[nr, nc] = nxt
                    stack_r[top] = nr
                    stack_c[top] = nc
                    top += 1
            nxt += 1
    return labels, nxt


@njit(cache=True)
def _finish(labels, count, min_points, row, col, point_range, pix_range, kept, ground, hb, hs):  # pragma: no cover
    """Drop segments under `min_points` pixels, renumber densely, and label every point whose
    range agrees with its pixel's nearest point (within the horizontal threshold)."""
    h, w = labels.shape
    sizes = np.zeros(count, dtype=np.int64)
    for r in range(h):
        for c in range(w):
            if labels[r, c] >= 0:
                sizes[labels[r, c]] += 1
    remap = np.full(count, -1, dtype=np.int32)
    nxt = 0
    for k in range(count):
        if sizes[k] >= min_points:
            remap[k] = nxt
            nxt += 1
    pixel = np.full((h, w), -1, dtype=np.int32)
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


def segment(
    image: RangeImage,
    ground: np.ndarray,
    sensor: SensorModel,
    config: SegmentationConfig | None = None,
) -> Segmentation:
    """Segment the non-ground pixels of `image`; `ground` is the (N,) per-point ground mask."""
    config = config or SegmentationConfig()
    h, w = image.shape
    index = image.index
    occupied = index >= 0
    ok = occupied.copy()
    ok[occupied] = ~ground[index[occupied]]
    el = sensor.elevations_rad()
    v_alpha = np.abs(np.diff(el)) if len(el) == h else np.full(h - 1, np.deg2rad(1.0))
    labels, count = _grow(
        image.range,
        ok,
        ~occupied,
        config.vertical_base,
        config.vertical_slope,
        config.horizontal_base,
        config.horizontal_slope,
        config.use_angle_criterion,
        np.tan(np.deg2rad(config.angle_threshold_deg)),
        v_alpha.astype(np.float32),
        np.float32(2.0 * np.pi / w),
        config.bridge_empty,
    )
    pixel, point, kept_count = _finish(
        labels, count, max(1, config.min_points), image.row, image.col, image.point_range, image.range,
        image.kept, ground, config.horizontal_base, config.horizontal_slope,
    )
    return Segmentation(pixel=pixel, point=point, count=int(kept_count))
