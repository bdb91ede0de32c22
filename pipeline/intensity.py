"""Intensity per sensor: measured from the data, normalised by rank, absent when it does not vary.

Sensors report intensity on scales of their own: KITTI's remission lies in [0, 1] with a median
near 0.3, an Ouster's calibrated reflectivity read as a KITTI `.bin` may peak at 0.01, a PCD may
hold raw 16-bit counts or nothing at all. A model trained on one scale reads another as a new
texture (the first shipped model called every segment of an intensity-free scan "car").

So a sequence's intensity is normalised per sensor, from the data: `measure` takes the quantiles
of the first readable frame's intensities (points at least `MIN_RHO` from the axis), they travel
with the sensor (`SensorModel.intensity_quantiles`, stored with an ingested sequence), and sample
canvases show each intensity scaled so that the sensor's 95th percentile reads `REFERENCE`
(`SampleConfig.intensity = "sensor"`): any rescaling of the raw values leaves them unchanged,
while the sensor's own contrast (a dark road, bright walls) stays. (Ranks among the quantiles
were tried first: they align any monotonic response too, but they are the ranks among the
frame's ground points as much as its objects', and a model trained on them classified 2-9
points fewer of the real frames' object points right, docs/default_model.md.) A sensor whose intensities do not vary (an xyz-only file reads as all 0)
has none: its canvases get an empty intensity channel, the geometry-only input the shipped model
is trained on by dropping the channel (`TrainingConfig.intensity_drop`); another sensor's
response curve is what its random power stands for (`TrainingConfig.intensity_gamma`).
"""

from __future__ import annotations

import numpy as np
from numba import njit

QUANTILES = 101  # p0, p1, ..., p100
MIN_RHO = 1.0  # metres: the car, the mount and placeholder points lie closer
MIN_POINTS = 100
ABSENT_SPREAD = 1e-6  # p100 - p0 at or below this: the intensity does not vary

REFERENCE = 0.5  # the canvas intensity of a sensor's 95th percentile
# Canvas intensity modes, as the numba renderer takes them.
RAW, NONE, SCALE = 0, 1, 2


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


def scale(quantiles: tuple[float, ...]) -> float:
    """The factor that takes a sensor's 95th percentile (its largest positive quantile at or
    below, when the sensor reports 0 that often) to REFERENCE."""
    q = np.asarray(quantiles, dtype=np.float64)
    top = q[: int(round(0.95 * (len(q) - 1))) + 1]
    top = top[top > 0]
    return REFERENCE / float(top[-1] if len(top) else q[-1])


def canvas_mode(sample_mode: str, quantiles: tuple[float, ...]) -> tuple[int, float]:
    """(mode, factor) of the renderer for `SampleConfig.intensity` and a sensor's quantiles: RAW
    (the values as read, clipped to [0, 1]) for "raw" or an unmeasured sensor, NONE (an empty
    channel) for a sensor without intensity, else SCALE by `scale(quantiles)`."""
    if sample_mode == "raw" or len(quantiles) < 2:
        return RAW, 1.0
    if is_absent(quantiles):
        return NONE, 0.0
    return SCALE, scale(quantiles)


@njit(cache=True)
def normalised(value, mode, factor):  # pragma: no cover - numba
    """A raw intensity as the canvas shows it, in [0, 1] (see `canvas_mode`)."""
    if mode == NONE:
        return 0.0
    return min(max(value * factor, 0.0), 1.0)
