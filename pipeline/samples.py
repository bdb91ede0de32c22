"""Segment statistics, the validity rule and sample canvases.

A segment with n points at distance d (sensor to centroid) is valid for a sample when
n > sigma and n / d > rho. Its sample covers a cuboid of h x w x l = 2.4 x 5 x 5 m centred on the
segment's centroid, its length along the viewing ray. The cuboid's angular window is rendered
from the range image onto an S x S canvas at a fixed metric scale (canvas column j looks at
azimuth phi_c + (1/2 - (j + 1/2)/S) * 2 atan(w/2 / d); canvas row i at elevation
el_c + (1/2 - (i + 1/2)/S) * 2 atan(h/2 / d)); pixels whose point lies outside the cuboid stay 0.

Sample layout: uint8 (C, S, S), C = 4 (or 3 without the foreground channel):
    0 height above ground, 0..max_height m -> 0..255 (clipped)
    1 range, 0..max_range m -> 1..255 (0 = empty pixel)
    2 intensity, 0..1 -> 0..255: scaled per sensor (its 95th percentile at 0.5), or the raw value
      (`SampleConfig.intensity`, `pipeline.intensity`); 0 everywhere when the sensor has none
    3 foreground: 255 on the segment's own points, 0 elsewhere
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from pipeline.config import SampleConfig
from pipeline.intensity import canvas_mode, normalised
from pipeline.range_image import RangeImage
from pipeline.scan import Scan
from pipeline.sensors import SensorModel


@dataclass(frozen=True)
class SegmentTable:
    """Per-segment statistics of one frame; every array has length S (segment ids 0..S-1).

    n_points: (S,) int32; centroid: (S, 3) float32 lidar frame; range: (S,) float32 sensor-to-centroid
    distance; valid: (S,) bool, valid for a sample.
    """

    n_points: np.ndarray
    centroid: np.ndarray
    range: np.ndarray
    valid: np.ndarray

    def __len__(self) -> int:
        return len(self.n_points)


def segment_table(points: np.ndarray, seg_point: np.ndarray, count: int, config: SampleConfig) -> SegmentTable:
    """Statistics of `count` segments from (N, 3) points and their (N,) segment ids (-1 = none)."""
    n, cen = _counts_and_centroids(points, seg_point, count)
    dist = np.linalg.norm(cen, axis=1).astype(np.float32)
    valid = is_valid(n, dist, config)
    return SegmentTable(n_points=n, centroid=cen, range=dist, valid=valid)


@njit(cache=True)
def _counts_and_centroids(points, seg_point, count):  # pragma: no cover - numba
    """(count,) int32 points per segment and (count, 3) float32 centroids, in one pass."""
    n = np.zeros(count, dtype=np.int32)
    sums = np.zeros((count, 3), dtype=np.float64)
    for i in range(seg_point.shape[0]):
        s = seg_point[i]
        if s >= 0:
            n[s] += 1
            for k in range(3):
                sums[s, k] += points[i, k]
    cen = np.zeros((count, 3), dtype=np.float32)
    for s in range(count):
        if n[s]:
            for k in range(3):
                cen[s, k] = sums[s, k] / n[s]
    return n, cen


def is_valid(n_points: np.ndarray, distance: np.ndarray, config: SampleConfig) -> np.ndarray:
    """(S,) bool: n > sigma and n / d > rho."""
    return (n_points > config.sigma) & (n_points / np.maximum(distance, 1e-3) > config.rho)


@njit(cache=True)
def _render(
    index, points, height, rng, intensity, seg_point, centers, seg_ids, rows, cols,
    half_h, half_w, half_l, max_height, max_range, fg_channel, i_mode, i_factor,
):  # pragma: no cover - numba
    v_count, size = rows.shape
    channels = 4 if fg_channel else 3
    out = np.zeros((v_count, channels, size, size), dtype=np.uint8)
    for v in range(v_count):
        cx = centers[v, 0]
        cy = centers[v, 1]
        cz = centers[v, 2]
        dxy = np.sqrt(cx * cx + cy * cy)
        ux = cx / dxy if dxy > 1e-6 else 1.0
        uy = cy / dxy if dxy > 1e-6 else 0.0
        for i in range(size):
            r = rows[v, i]
            if i > 0 and r == rows[v, i - 1]:
                # canvas rows repeat each laser ring (S rows over a few rings): copy the row above
                for ch in range(channels):
                    for j in range(size):
                        out[v, ch, i, j] = out[v, ch, i - 1, j]
                continue
            for j in range(size):
                if j > 0 and cols[v, j] == cols[v, j - 1]:
                    for ch in range(channels):
                        out[v, ch, i, j] = out[v, ch, i, j - 1]
                    continue
                p = index[r, cols[v, j]]
                if p < 0:
                    continue
                dx = points[p, 0] - cx
                dy = points[p, 1] - cy
                dz = points[p, 2] - cz
                radial = dx * ux + dy * uy
                tangential = -dx * uy + dy * ux
                if abs(dz) > half_h or abs(tangential) > half_w or abs(radial) > half_l:
                    continue
                hv = height[p] / max_height
                hv = min(max(hv, 0.0), 1.0)
                out[v, 0, i, j] = np.uint8(hv * 255.0 + 0.5)
                rv = min(rng[p] / max_range, 1.0)
                out[v, 1, i, j] = np.uint8(1.0 + rv * 254.0 + 0.5)
                iv = normalised(np.float64(intensity[p]), i_mode, i_factor)
                out[v, 2, i, j] = np.uint8(iv * 255.0 + 0.5)
                if fg_channel and seg_point[p] == seg_ids[v]:
                    out[v, 3, i, j] = 255
    return out


def sample_windows(
    centers: np.ndarray, sensor: SensorModel, width: int, config: SampleConfig
) -> tuple[np.ndarray, np.ndarray]:
    """Range-image rows (V, S) and columns (V, S) that each canvas row / column looks at."""
    size = config.size
    h, w, _ = config.cuboid_hwl
    dxy = np.maximum(np.hypot(centers[:, 0], centers[:, 1]), 0.5)
    phi = np.arctan2(centers[:, 1], centers[:, 0])
    el = np.arctan2(centers[:, 2], dxy)
    t = 0.5 - (np.arange(size) + 0.5) / size  # (S,) +1/2 .. -1/2
    az = phi[:, None] + t[None, :] * 2.0 * np.arctan(w / 2.0 / dxy)[:, None]  # (V, S), left to right
    cols = np.mod(np.floor((0.5 - az / (2.0 * np.pi)) * width), width).astype(np.int32)
    elev = el[:, None] + t[None, :] * 2.0 * np.arctan(h / 2.0 / dxy)[:, None]  # (V, S), top to bottom
    beams = sensor.elevations_rad()[::-1]  # ascending
    pos = np.clip(np.searchsorted(beams, elev), 1, len(beams) - 1)
    nearer_low = (elev - beams[pos - 1]) < (beams[pos] - elev)
    rows = (len(beams) - 1 - np.where(nearer_low, pos - 1, pos)).astype(np.int32)
    return rows, cols


def render_samples(
    scan: Scan,
    image: RangeImage,
    height: np.ndarray,
    seg_point: np.ndarray,
    table: SegmentTable,
    sensor: SensorModel,
    config: SampleConfig,
) -> tuple[np.ndarray, np.ndarray]:
    """Samples of the valid segments: (V, C, S, S) uint8 and their (V,) int32 segment ids."""
    seg_ids = np.flatnonzero(table.valid).astype(np.int32)
    return render_segments(scan, image, height, seg_point, table.centroid, seg_ids, sensor, config), seg_ids


def render_segments(
    scan: Scan,
    image: RangeImage,
    height: np.ndarray,
    seg_point: np.ndarray,
    centroid: np.ndarray,
    seg_ids: np.ndarray,
    sensor: SensorModel,
    config: SampleConfig,
) -> np.ndarray:
    """(V, C, S, S) uint8 samples of the segments `seg_ids` (V,), centred on `centroid[seg_ids]`
    ((S_all, 3) lidar-frame centroids); a track split re-renders the two parts of a cut segment."""
    if len(seg_ids) == 0:
        return np.zeros((0, config.channels, config.size, config.size), np.uint8)
    centers = centroid[seg_ids].astype(np.float64)
    rows, cols = sample_windows(centers, sensor, image.shape[1], config)
    h, w, length = config.cuboid_hwl
    i_mode, i_factor = canvas_mode(config.intensity, sensor.intensity_quantiles)
    out = _render(
        image.index, scan.points, height.astype(np.float32), image.point_range, scan.intensity, seg_point,
        centers, seg_ids, rows, cols, h / 2.0, w / 2.0, length / 2.0,
        float(config.max_height), float(config.max_range), config.foreground_channel, i_mode, i_factor,
    )
    return out
