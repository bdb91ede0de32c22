"""Spherical projection of a scan onto a range image.

Layout (see docs/conventions.md): rows are beams (row 0 = top beam, taken from `Scan.ring`),
columns are azimuth bins, `c = floor((0.5 - atan2(y, x) / (2 pi)) * W) mod W`, so column W/2
looks forward and columns wrap behind the sensor. Each pixel keeps the nearest point that
falls into it; every point keeps its own pixel.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit, prange

from pipeline.config import RangeImageConfig
from pipeline.scan import Scan
from pipeline.sensors import SensorModel


@dataclass(frozen=True)
class RangeImage:
    """A projected scan.

    index: (H, W) int32 point index of the pixel's nearest point, -1 = empty.
    range: (H, W) float32 range of that point in metres, 0 = empty.
    row:   (N,) int16 pixel row of every point of the scan.
    col:   (N,) int32 pixel column of every point of the scan.
    point_range: (N,) float32 range of every point.
    kept:  (N,) bool, points inside [min_range, max_range] and outside the ego box (others have no
           pixel role).
    """

    index: np.ndarray
    range: np.ndarray
    row: np.ndarray
    col: np.ndarray
    point_range: np.ndarray
    kept: np.ndarray

    @property
    def shape(self) -> tuple[int, int]:
        return self.index.shape  # type: ignore[return-value]

    def owner_mask(self) -> np.ndarray:
        """(N,) bool: points that own their pixel (the nearest point of it)."""
        owner = np.zeros(len(self.row), dtype=bool)
        idx = self.index[self.index >= 0]
        owner[idx] = True
        return owner


def azimuth_columns(points: np.ndarray, width: int) -> np.ndarray:
    """(N,) int32 column of each (N, 3) point for a range image `width` columns wide."""
    phi = np.arctan2(points[:, 1], points[:, 0])
    col = np.floor((0.5 - phi / (2.0 * np.pi)) * width).astype(np.int64)
    return np.mod(col, width).astype(np.int32)


def column_azimuth(col: np.ndarray | float, width: int) -> np.ndarray:
    """Azimuth (rad) of the centre of column(s) `col`; inverse of `azimuth_columns`."""
    return (0.5 - (np.asarray(col, dtype=np.float64) + 0.5) / width) * 2.0 * np.pi


def elevation_rows(points: np.ndarray, sensor: SensorModel) -> np.ndarray:
    """(N,) int16 row of the beam whose elevation is nearest to each point's elevation."""
    el = np.arctan2(points[:, 2], np.hypot(points[:, 0], points[:, 1]))
    beams = sensor.elevations_rad()[::-1]  # ascending for searchsorted
    pos = np.clip(np.searchsorted(beams, el), 1, len(beams) - 1)
    nearer_low = (el - beams[pos - 1]) < (beams[pos] - el)
    asc = np.where(nearer_low, pos - 1, pos)
    return (len(beams) - 1 - asc).astype(np.int16)


NO_BOX = np.array([1, -1, 1, -1, 1, -1], dtype=np.float32)  # x, y, z ranges with min > max


@njit(cache=True, inline="always")
def fast_atan2(y, x):  # pragma: no cover - numba
    """float32 atan2 by an odd minimax polynomial of atan on [0, 1] (max error ~2e-6 rad,
    0.1 % of a 2160-column bin; several times cheaper than atan2f, which dominated the projection)."""
    ax = abs(x)
    ay = abs(y)
    # selects, not branches, so that loops over points vectorise; max(mx, tiny) makes atan2(0, 0) 0
    t = min(ax, ay) / max(max(ax, ay), np.float32(1e-30))
    s = t * t
    r = t * (
        np.float32(0.99997726)
        + s * (
            np.float32(-0.33262347)
            + s * (np.float32(0.19354346) + s * (np.float32(-0.11643287) + s * (np.float32(0.05265332) - s * np.float32(0.0117212))))
        )
    )
    r = np.float32(1.57079637) - r if ay > ax else r
    r = np.float32(3.14159274) - r if x < 0.0 else r
    return -r if y < 0.0 else r


@njit(cache=True, parallel=True)
def _project_kernel(points, ring, height, width, min_range, max_range, box):  # pragma: no cover - numba
    n = points.shape[0]
    index = np.full((height, width), -1, dtype=np.int32)
    rimg = np.zeros((height, width), dtype=np.float32)
    col = np.empty(n, dtype=np.int32)
    rng = np.empty(n, dtype=np.float32)
    kept = np.zeros(n, dtype=np.bool_)
    inv_two_pi = np.float32(0.5 / np.pi)
    half = np.float32(0.5)
    fw = np.float32(width)
    # 1. range, column and validity per point (points in parallel), from contiguous copies of
    # x, y and z: the loop then vectorises (2.4x faster than reading the (N, 3) rows)
    xs = np.ascontiguousarray(points[:, 0])
    ys = np.ascontiguousarray(points[:, 1])
    zs = np.ascontiguousarray(points[:, 2])
    for i in prange(n):
        x = xs[i]
        y = ys[i]
        z = zs[i]
        r = np.sqrt(x * x + y * y + z * z)
        rng[i] = r
        # float32 throughout: a column is 0.17 deg (2.9e-3 rad) wide
        c = np.int32(np.floor((half - fast_atan2(y, x) * inv_two_pi) * fw))
        # the angle term lies in [0, 1] up to float32 rounding: wrap without an integer division
        c = c - width if c >= width else c
        col[i] = c + width if c < 0 else c
        row = ring[i]
        inside = (box[0] <= x) & (x <= box[1]) & (box[2] <= y) & (y <= box[3]) & (box[4] <= z) & (z <= box[5])
        # the vehicle's own body is not kept
        kept[i] = (r >= min_range) & (r <= max_range) & (row >= 0) & (row < height) & ~inside
    # 2. each pixel keeps its nearest point (serial: points compete for pixels)
    for i in range(n):
        if not kept[i]:
            continue
        row = ring[i]
        c = col[i]
        j = index[row, c]
        if j < 0 or rng[i] < rimg[row, c]:
            index[row, c] = i
            rimg[row, c] = rng[i]
    return index, rimg, col, rng, kept


def project(scan: Scan, sensor: SensorModel, config: RangeImageConfig | None = None) -> RangeImage:
    """Project `scan` onto an (H, W) range image; H = sensor beams, W = config width or the sensor's.
    Points in the ego box (the config's, else the sensor's) are not kept: the vehicle's own body."""
    config = config or RangeImageConfig()
    height = sensor.n_rings
    width = config.width or sensor.width
    box = np.asarray(sensor.ego_box if config.ego_box is None else config.ego_box, dtype=np.float32)
    if box.shape != (6,):
        box = NO_BOX  # the kernel tests every point against a box: one that holds nothing
    index, rimg, col, rng, kept = _project_kernel(
        scan.points, scan.ring, height, width, np.float32(config.min_range), np.float32(config.max_range), box
    )
    return RangeImage(index=index, range=rimg, row=scan.ring, col=col, point_range=rng, kept=kept)
