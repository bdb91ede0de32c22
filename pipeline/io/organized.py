"""Organized scans: H x W points stored row by row, a point of zeros where a pixel has no return.

Some exports keep a sensor's image layout in a plain point file (an Ouster OS1-64 scan saved as a
KITTI `.bin` of 64 x 2048 points). Such a cloud is recognised by its geometry, not by its size
alone: for some split N = H x W, every row must be one beam that turns once around the sensor
(a pixel's azimuth is its column's, `+-360 deg * c / W`, up to one offset per row, which also
covers staggered layouts), and the rows' elevations must run monotonically (top-down or
bottom-up).
"""

from __future__ import annotations

import numpy as np

from pipeline.io.rings import segment_medians

MIN_ROWS, MAX_ROWS = 2, 256
MIN_COLUMNS = 64
MIN_RETURNS = 10  # returns a row needs to be judged
COLUMN_TOLERANCE = 1.5  # columns a pixel's azimuth may stray from its column's


def returns(points: np.ndarray) -> np.ndarray:
    """(N,) bool: the points that are returns (finite and not all-zero)."""
    p = np.asarray(points)
    return np.isfinite(p).all(axis=1) & (p != 0).any(axis=1)


def _column_error(az: np.ndarray, hit: np.ndarray, width: int) -> float:
    """How far (H, C) azimuths (radians) of the first C columns of rows `width` wide stray from
    their columns: the 90th percentile, in columns, of the returns' deviation from their row's
    offset, for the better of counter-clockwise and clockwise rows (inf when no row has
    MIN_RETURNS returns)."""
    judged = hit.sum(axis=1) >= MIN_RETURNS
    if not judged.any():
        return np.inf
    col = np.arange(az.shape[1]) * (2.0 * np.pi / width)  # the first columns of a width-W row
    best = np.inf
    for sign in (1.0, -1.0):
        phase = np.where(hit, np.exp(1j * (az - sign * col[None, :])), 0.0)[judged]  # (R, C)
        offset = np.exp(-1j * np.angle(phase.sum(axis=1)))  # (R,) the row's circular mean offset
        dev = np.abs(np.angle((phase * offset[:, None])[hit[judged]])) * width / (2 * np.pi)
        best = min(best, float(np.percentile(dev, 90)))
    return best


def _monotonic_rows(elevation: np.ndarray, hit: np.ndarray) -> int:
    """+1 when the rows' median elevations fall from row 0 down, -1 when they rise, 0 otherwise."""
    h = elevation.shape[0]
    rows = np.repeat(np.arange(h), elevation.shape[1]).reshape(elevation.shape)
    med = segment_medians(elevation[hit], rows[hit], h)
    med = med[~np.isnan(med)]
    if len(med) < 2:
        return 0
    d = np.diff(med)
    if np.mean(d < 0) >= 0.9:
        return 1
    if np.mean(d > 0) >= 0.9:
        return -1
    return 0


def organized_shape(points: np.ndarray) -> tuple[int, int, bool] | None:
    """(H, W, top_first) when the (N, 3) cloud is an organized H x W scan (see the module
    docstring), else None. Of the splits N = H x W that fit, the one whose azimuths follow the
    columns most closely wins. top_first: row 0 is the top beam (else the bottom one)."""
    n = len(points)
    hit_all = returns(points)
    if n < MIN_ROWS * MIN_COLUMNS or hit_all.sum() < MIN_RETURNS * MIN_ROWS:
        return None
    p = np.where(hit_all[:, None], np.asarray(points, dtype=np.float64), 0.0)
    az_all = np.arctan2(p[:, 1], p[:, 0])
    el_all = np.arctan2(p[:, 2], np.hypot(p[:, 0], p[:, 1]))
    best: tuple[float, int, int, bool] | None = None
    for h in range(MIN_ROWS, MAX_ROWS + 1):
        if n % h or n // h < MIN_COLUMNS:
            continue
        w = n // h
        hit, az = hit_all.reshape(h, w), az_all.reshape(h, w)
        # a few rows' first columns first: most splits fail there (a row's azimuths do not follow
        # its columns from the start), which keeps the search at ~10 ms for an unorganized cloud
        probe = np.linspace(0, h - 1, min(h, 8)).astype(np.int64)
        span = min(w, 1024)
        if _column_error(az[probe, :span], hit[probe, :span], w) > COLUMN_TOLERANCE:
            continue
        error = _column_error(az, hit, w)
        if error > COLUMN_TOLERANCE or (best is not None and error >= best[0]):
            continue
        direction = _monotonic_rows(el_all.reshape(h, w), hit)
        if direction:
            best = (error, h, w, direction > 0)
    return None if best is None else best[1:]


def organized_rows(height: int, width: int, top_first: bool) -> np.ndarray:
    """(H * W,) int16 beam row of every pixel of an organized scan, 0 = top beam."""
    rows = np.repeat(np.arange(height, dtype=np.int16), width)
    return rows if top_first else (height - 1 - rows).astype(np.int16)
