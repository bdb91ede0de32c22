"""Scans synthesised from range images, so every point lands on a known pixel."""

from __future__ import annotations

import numpy as np

from pipeline.range_image import column_azimuth
from pipeline.scan import Scan
from pipeline.sensors import SensorModel


def scan_from_range_image(rimg: np.ndarray, sensor: SensorModel, width: int | None = None) -> Scan:
    """A scan with one point per non-zero pixel of `rimg` (H, W), at the pixel's centre direction."""
    width = width or rimg.shape[1]
    rows, cols = np.nonzero(rimg > 0)
    r = rimg[rows, cols].astype(np.float64)
    el = sensor.elevations_rad()[rows]
    az = column_azimuth(cols, width)
    pts = np.stack([r * np.cos(el) * np.cos(az), r * np.cos(el) * np.sin(az), r * np.sin(el)], axis=1)
    return Scan(pts.astype(np.float32), np.full(len(r), 0.5, np.float32), rows.astype(np.int16))


def flat_ground(sensor: SensorModel, width: int, height_m: float = 1.8, max_range: float = 60.0) -> np.ndarray:
    """(H, W) ranges of a flat ground plane `height_m` below the sensor (0 where beams miss)."""
    el = sensor.elevations_rad()
    r = np.where(el < -0.01, height_m / np.sin(-np.minimum(el, -1e-3)), 0.0)
    r = np.where(r < max_range, r, 0.0)
    return np.repeat(r[:, None], width, axis=1)


def add_box(rimg: np.ndarray, rows: slice, cols: slice, rng: float) -> None:
    """Paint an object at range `rng` over the given pixel block (nearest wins)."""
    block = rimg[rows, cols]
    rimg[rows, cols] = np.where((block == 0) | (block > rng), rng, block)
