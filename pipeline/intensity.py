"""Intensity per sensor: measured from the data, normalised by rank, absent when it does not vary.

Sensors report intensity on scales of their own: KITTI's remission lies in [0, 1] with a median
near 0.3, an Ouster's calibrated reflectivity read as a KITTI `.bin` may peak at 0.01, a PCD may
hold raw 16-bit counts or nothing at all. A model trained on one scale reads another as a new
texture (the first shipped model called every segment of an intensity-free scan "car").

So a sequence's intensity is normalised per sensor, from the data: `measure` takes the quantiles
of the first readable frame's intensities (points at least `MIN_RHO` from the axis), they travel
with the sensor (`SensorModel.intensity_quantiles`, stored with an ingested sequence), and sample
canvases show each point's rank among them (`SampleConfig.intensity = "sensor"`), which any
monotonic rescaling of the raw values leaves unchanged. A sensor whose intensities do not vary
(an xyz-only file reads as all 0) has none: its canvases get an empty intensity channel, the
geometry-only input the shipped model is trained on by dropping the channel
(`TrainingConfig.intensity_drop`).
"""

from __future__ import annotations

import numpy as np
from numba import njit

QUANTILES = 101  # p0, p1, ..., p100
MIN_RHO = 1.0  # metres: the car, the mount and placeholder points lie closer
MIN_POINTS = 100
ABSENT_SPREAD = 1e-6  # p100 - p0 at or below this: the intensity does not vary

# Canvas intensity modes (`_mode`), as the numba renderer takes them.
RAW, NONE, RANK = 0, 1, 2


def measure(points: np.ndarray, intensity: np.ndarray) -> tuple[float, ...]:
    """QUANTILES quantiles (p0..p100) of the intensities (N,) of (N, 3) points at least MIN_RHO
    from the axis, rounded to 6 decimals; () when fewer than MIN_POINTS such points are finite."""
    p = np.asarray(points, dtype=np.float64)
    i = np.asarray(intensity, dtype=np.float64)
    keep = np.isfinite(i) & np.isfinite(p).all(axis=1) & (np.hypot(p[:, 0], p[:, 1]) >= MIN_RHO)
    if keep.sum() < MIN_POINTS:
        return ()
    q = np.percentile(i[keep], np.linspace(0.0, 100.0, QUANTILES))
    return tuple(float(round(v, 6)) for v in q)


def is_absent(quantiles: tuple[float, ...]) -> bool:
    """Whether measured quantiles show no intensity (a constant); () is unmeasured, not absent."""
    return len(quantiles) >= 2 and quantiles[-1] - quantiles[0] <= ABSENT_SPREAD


def canvas_mode(sample_mode: str, quantiles: tuple[float, ...]) -> tuple[int, np.ndarray]:
    """(mode, (Q,) float64 table) of the renderer for `SampleConfig.intensity` and a sensor's
    quantiles: RAW (the values as read, clipped to [0, 1]) for "raw" or an unmeasured sensor, NONE
    (an empty channel) for a sensor without intensity, else RANK."""
    if sample_mode == "raw" or len(quantiles) < 2:
        return RAW, np.zeros(0)
    if is_absent(quantiles):
        return NONE, np.zeros(0)
    return RANK, np.asarray(quantiles, dtype=np.float64)


@njit(cache=True)
def normalised(value, mode, table):  # pragma: no cover - numba
    """A raw intensity as the canvas shows it, in [0, 1] (see `canvas_mode`). RANK: the value's
    place among the sensor's quantiles, interpolated, the mid-rank of a run of equal quantiles
    (a sensor whose floor holds a third of its returns puts them at 1/6, not 1/3)."""
    if mode == RAW:
        return min(max(value, 0.0), 1.0)
    if mode == NONE:
        return 0.0
    q = table.shape[0]
    lo = np.searchsorted(table, value, side="left")
    hi = np.searchsorted(table, value, side="right")
    if hi == 0:
        return 0.0
    if lo == q:
        return 1.0
    if hi > lo:  # the value is a quantile (maybe several equal ones)
        return 0.5 * (lo + hi - 1) / (q - 1)
    a, b = table[lo - 1], table[lo]
    return (lo - 1 + (value - a) / (b - a)) / (q - 1)
