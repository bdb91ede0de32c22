"""Surface texture statistics of labelled scans: how each class looks to a spinning LiDAR.

They are measured alike on real SemanticKITTI scans and on simulated ones, so that the
simulator's materials can be tuned until the two agree (docs/simulator.md). Per SemanticKITTI
class, over the points of the class within `MAX_RANGE` m:

- row residual: RMS residual of a least-squares line fitted to range against column over a
  7-pixel window of a range-image row (3 columns either side), using the window's pixels of the
  centre's class (at least 5 of 7). A wall's returns lie on a line (residual = sensor noise);
  foliage returns come from leaves at scattered depths.
- beam residual: the same along a column over 5 beams (at least 4 of 5): the scatter between
  neighbouring beams. It depends on the beam spacing, so compare it between scans of one sensor.
- missing share: empty pixels with a pixel of the class within 3 columns on both sides in the same
  row (holes in the class's surface), over those holes plus the class's pixels.
- intensity: the remission of the class's points.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pipeline.range_image import project
from pipeline.scan import Scan
from pipeline.sensors import SensorModel

CLASSES: dict[int, str] = {70: "vegetation", 50: "building", 10: "car", 71: "trunk", 51: "fence"}
MAX_RANGE = 40.0
QUANTILES = (10, 25, 50, 75, 90)
ROW_HALF, ROW_MIN = 3, 5
BEAM_HALF, BEAM_MIN = 2, 4
HOLE_REACH = 3
RANGE_BINS = ((0.0, 10.0), (10.0, 20.0), (20.0, MAX_RANGE))


@dataclass(frozen=True)
class ClassImage:
    """A range image with a class per pixel.

    range: (H, W) float64 metres, 0 = empty; cls: (H, W) int64 SemanticKITTI id, -1 = empty.
    """

    range: np.ndarray
    cls: np.ndarray


def class_image(scan: Scan, sensor: SensorModel) -> ClassImage:
    """Project a labelled scan; moving cars (252) count as cars (10)."""
    assert scan.semantic is not None, "texture statistics need labels"
    img = project(scan, sensor)
    sem = scan.semantic.astype(np.int64) & 0xFFFF
    sem = np.where(sem == 252, 10, sem)
    cls = np.where(img.index >= 0, sem[np.maximum(img.index, 0)], -1)
    return ClassImage(img.range.astype(np.float64), cls)


def line_residual(rng: np.ndarray, cls: np.ndarray, half: int, min_count: int, axis: int) -> np.ndarray:
    """(H, W) RMS residual of a line fit to range over 2 half + 1 pixels along `axis` (1 = row,
    wrapping; 0 = column), over the window's pixels of the centre's class; NaN where fewer than
    `min_count` take part or the centre is empty."""
    n = sx = sy = sxx = sxy = syy = np.zeros(rng.shape)
    for k in range(-half, half + 1):
        rk = np.roll(rng, -k, axis)
        ck = np.roll(cls, -k, axis)
        good = (ck == cls) & (cls >= 0)
        if axis == 0:  # no wrap between the top and bottom beams
            good &= _rows_valid(rng.shape[0], k)[:, None]
        y = np.where(good, rk - rng, 0.0)
        g = good.astype(np.float64)
        n = n + g
        sx = sx + g * k
        sxx = sxx + g * k * k
        sy = sy + y
        sxy = sxy + y * k
        syy = syy + y * y
    den = n * sxx - sx * sx
    ok = (n >= min_count) & (cls >= 0) & (den > 0)
    den = np.where(ok, den, 1.0)
    b = (n * sxy - sx * sy) / den
    a = (sy - b * sx) / np.maximum(n, 1.0)
    sse = syy - a * sy - b * sxy  # sum of squared residuals of the least-squares line
    return np.where(ok, np.sqrt(np.maximum(sse, 0.0) / np.maximum(n - 2.0, 1.0)), np.nan)


def _rows_valid(h: int, k: int) -> np.ndarray:
    r = np.arange(h) + k
    return (r >= 0) & (r < h)


def holes(cls: np.ndarray, reach: int = HOLE_REACH) -> np.ndarray:
    """(H, W) int64: the class an empty pixel is a hole in (a pixel of that class within `reach`
    columns on both sides, the nearest on each side), -1 elsewhere."""
    left = _nearest_class(cls, reach, -1)
    right = _nearest_class(cls, reach, 1)
    return np.where((cls < 0) & (left >= 0) & (left == right), left, -1)


def _nearest_class(cls: np.ndarray, reach: int, step: int) -> np.ndarray:
    out = np.full(cls.shape, -1, np.int64)
    for k in range(reach, 0, -1):  # nearer pixels overwrite farther ones
        ck = np.roll(cls, -step * k, 1)
        out = np.where(ck >= 0, ck, out)
    return out


@dataclass
class TextureAccumulator:
    """Collects per-class samples over scans; `summary()` gives quantiles and shares."""

    sensor: SensorModel
    row: dict[int, list[np.ndarray]]
    row_range: dict[int, list[np.ndarray]]
    beam: dict[int, list[np.ndarray]]
    intensity: dict[int, list[np.ndarray]]
    pixels: dict[int, int]
    missing: dict[int, int]

    @classmethod
    def empty(cls, sensor: SensorModel) -> TextureAccumulator:
        return cls(sensor, {}, {}, {}, {}, {}, {})

    def add(self, scan: Scan) -> None:
        ci = class_image(scan, self.sensor)
        near = (ci.range > 0) & (ci.range <= MAX_RANGE)
        row = line_residual(ci.range, ci.cls, ROW_HALF, ROW_MIN, 1)
        beam = line_residual(ci.range, ci.cls, BEAM_HALF, BEAM_MIN, 0)
        hole = holes(ci.cls)
        sem = scan.semantic.astype(np.int64) & 0xFFFF
        sem = np.where(sem == 252, 10, sem)
        dist = np.linalg.norm(scan.points, axis=1)
        for c in CLASSES:
            m = near & (ci.cls == c)
            self.row.setdefault(c, []).append(row[m & ~np.isnan(row)])
            self.row_range.setdefault(c, []).append(ci.range[m & ~np.isnan(row)])
            self.beam.setdefault(c, []).append(beam[m & ~np.isnan(beam)])
            self.pixels[c] = self.pixels.get(c, 0) + int(m.sum())
            self.missing[c] = self.missing.get(c, 0) + int((hole == c).sum())
            self.intensity.setdefault(c, []).append(scan.intensity[(sem == c) & (dist <= MAX_RANGE)])

    def summary(self) -> dict[str, dict]:
        """Per class name: pixels, quantiles (QUANTILES, in cm for residuals) and shares."""
        out = {}
        for c, name in CLASSES.items():
            row = np.concatenate(self.row.get(c, [np.zeros(0)]))
            dist = np.concatenate(self.row_range.get(c, [np.zeros(0)]))
            beam = np.concatenate(self.beam.get(c, [np.zeros(0)]))
            inten = np.concatenate(self.intensity.get(c, [np.zeros(0)]))
            px = self.pixels.get(c, 0)
            if px == 0:
                continue
            out[name] = {
                "pixels": px,
                "row_residual_cm": _quantiles(100.0 * row),
                "row_residual_over_3cm": _share(row > 0.03),
                "row_residual_median_by_range_cm": {
                    f"{lo:g}-{hi:g}": _median_cm(row[(dist >= lo) & (dist < hi)]) for lo, hi in RANGE_BINS
                },
                "beam_residual_cm": _quantiles(100.0 * beam),
                "missing_share": round(self.missing[c] / (self.missing[c] + px), 4),
                "intensity": _quantiles(inten),
            }
        return out


def _quantiles(v: np.ndarray) -> list[float] | None:
    return [round(float(x), 3) for x in np.percentile(v, QUANTILES)] if len(v) else None


def _median_cm(v: np.ndarray) -> float | None:
    return round(100.0 * float(np.median(v)), 3) if len(v) else None


def _share(m: np.ndarray) -> float | None:
    return round(float(m.mean()), 4) if len(m) else None


def texture_statistics(scans, sensor: SensorModel) -> dict[str, dict]:
    """Per-class texture statistics over labelled `scans` (an iterable of `Scan`)."""
    acc = TextureAccumulator.empty(sensor)
    for scan in scans:
        acc.add(scan)
    return acc.summary()
