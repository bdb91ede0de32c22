"""Organized scans: H x W points stored row by row or column by column, a point of zeros where a
pixel has no return.

Some exports keep a sensor's image layout in a plain point file (an Ouster OS1-64 scan saved as a
KITTI `.bin` of 64 x 2048 points, row by row, or column by column as the sensor fires them). Such
a cloud is recognised by its geometry, not by its size alone: for some split N = H x W, in either
storage order, every row must be one beam that turns once around the sensor (a pixel's azimuth is
its column's, `+-360 deg * c / W`, up to one offset per row, which also covers staggered layouts),
and the rows' elevations must run monotonically (top-down or bottom-up).
"""

from __future__ import annotations

from typing import NamedTuple

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
    """+1 when the rows' median elevations fall from row 0 down, -1 when they rise, 0 otherwise
    (also when they start again from the top: rows that hold two scans, or two columns each)."""
    h = elevation.shape[0]
    rows = np.repeat(np.arange(h), elevation.shape[1]).reshape(elevation.shape)
    med = segment_medians(elevation[hit], rows[hit], h)
    med = med[~np.isnan(med)]
    if len(med) < 2:
        return 0
    d = np.diff(med)
    # a step back by a quarter of the span is a restart: two scans' rows (or a column pair) in one
    span = float(med.max() - med.min())
    if np.mean(d < 0) >= 0.9 and d.max() < 0.25 * span:
        return 1
    if np.mean(d > 0) >= 0.9 and d.min() > -0.25 * span:
        return -1
    return 0


class OrganizedShape(NamedTuple):
    """An organized layout: H rows (beams) x W columns; top_first: row 0 is the top beam (else
    the bottom one); column_major: stored column by column (point i is row i % H of column
    i // H), else row by row."""

    height: int
    width: int
    top_first: bool
    column_major: bool = False


def _as_image(values: np.ndarray, h: int, w: int, column_major: bool) -> np.ndarray:
    """(H, W, ...) view of per-point `values` (N, ...) stored row by row or column by column."""
    if column_major:
        return np.swapaxes(values.reshape(w, h, *values.shape[1:]), 0, 1)
    return values.reshape(h, w, *values.shape[1:])


def organized_shape(points: np.ndarray) -> OrganizedShape | None:
    """The layout when the (N, 3) cloud is an organized H x W scan (see the module docstring),
    else None. Of the splits N = H x W and storage orders that fit, the one whose azimuths follow
    the columns most closely wins."""
    n = len(points)
    hit_all = returns(points)
    if n < MIN_ROWS * MIN_COLUMNS or hit_all.sum() < MIN_RETURNS * MIN_ROWS:
        return None
    p = np.where(hit_all[:, None], np.asarray(points, dtype=np.float64), 0.0)
    az_all = np.arctan2(p[:, 1], p[:, 0])
    el_all = np.arctan2(p[:, 2], np.hypot(p[:, 0], p[:, 1]))
    best: tuple[float, OrganizedShape] | None = None
    for h in range(MIN_ROWS, MAX_ROWS + 1):
        if n % h or n // h < MIN_COLUMNS:
            continue
        w = n // h
        for column_major in (False, True):
            hit, az = _as_image(hit_all, h, w, column_major), _as_image(az_all, h, w, column_major)
            # a few rows' first columns first: most splits fail there (a row's azimuths do not
            # follow its columns from the start), which keeps the search at ~20 ms for an
            # unorganized cloud
            probe = np.linspace(0, h - 1, min(h, 8)).astype(np.int64)
            span = min(w, 1024)
            if _column_error(az[probe, :span], hit[probe, :span], w) > COLUMN_TOLERANCE:
                continue
            error = _column_error(az, hit, w)
            if error > COLUMN_TOLERANCE or (best is not None and error >= best[0]):
                continue
            direction = _monotonic_rows(_as_image(el_all, h, w, column_major), hit)
            if direction:
                best = (error, OrganizedShape(h, w, direction > 0, column_major))
    return None if best is None else best[1]


def organized_rows(shape: OrganizedShape) -> np.ndarray:
    """(H * W,) int16 beam row of every stored point of an organized scan, 0 = top beam."""
    h, w = shape.height, shape.width
    rows = np.tile(np.arange(h, dtype=np.int16), w) if shape.column_major else np.repeat(np.arange(h, dtype=np.int16), w)
    return rows if shape.top_first else (h - 1 - rows).astype(np.int16)
