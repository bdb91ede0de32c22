"""How the points of a cloud without ring field become range-image rows, and the sensor they show.

Decided once per sequence, on its first frame, in this order:

1. **organized layout**: H x W points row by row or column by column, zeros where no return
   (`pipeline.io.organized`);
   rows are the layout's rows and the width is W;
2. **scan order**: one laser's revolution after the other (KITTI `.bin`; `pipeline.io.rings`);
3. **elevation histogram**: an unordered cloud's beams from its elevations (`pipeline.io.beams`);
4. **default**: nothing shows (a handful of points): HDL-64E, rows by nearest elevation.

The sensor is the preset whose beams match the measured ones, else a model of the measured beams
(`pipeline.sensors.sensor_from_elevations`). Every later frame is read the same way
(`Layout.rows`); a frame that does not fit (an organized file of another size, a frame whose scan
order breaks) falls back to scan order, then to the beams of the first frame.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np
from numba import njit

from pipeline.io.beams import MIN_RHO, azimuth_coverage, beam_rows, find_beams
from pipeline.io.organized import OrganizedShape, organized_rows, organized_shape, returns
from pipeline.io.rings import scan_order_rings, segment_medians
from pipeline.sensors import PRESETS, SensorModel, sensor_from_elevations

DEFAULT_SENSOR = "hdl64e"


@dataclass(frozen=True)
class RingRecovery:
    """Recovered rows of a scan.

    ring:   (N,) int16 row, 0 = top beam, in [0, n_rings).
    method: "scan_order" or "elevation" (sector clusters aligned to the beams, `beam_rows`).
    found:  segments found in scan order (0 when the order showed no rings).
    """

    ring: np.ndarray
    method: str
    found: int


def recover_rings(
    points: np.ndarray, sensor: SensorModel, beams_deg: np.ndarray | None = None, origin_height: float = 0.0
) -> RingRecovery:
    """Rows (0 = top) of points (N, 3): scan order when it shows the sensor's beam count, else the
    points' elevations aligned to `beams_deg` (B,) (default: the sensor's) seen from
    `origin_height` metres above the origin."""
    rows, found = scan_order_rings(points, sensor.n_rings)
    if rows is not None:
        return RingRecovery(rows.astype(np.int16), "scan_order", found)
    beams = np.asarray(sensor.elevations_deg if beams_deg is None else beams_deg, dtype=np.float64)
    return RingRecovery(beam_rows(points, beams, origin_height), "elevation", found)


@dataclass(frozen=True)
class Layout:
    """The rows of a sequence's frames.

    sensor:    the sensor model found.
    how:       "organized layout", "scan order", "elevation histogram" or "default"; "given"
               when the sensor came from elsewhere (a flag, metadata).
    organized: the shape of an organized layout (`pipeline.io.organized.OrganizedShape`), else None.
    beams_deg: (B,) float64 elevations (descending, degrees, seen from `origin_height` m above the
               origin) that rows are aligned to when the scan order does not show them.
    """

    sensor: SensorModel
    how: str
    organized: OrganizedShape | None
    beams_deg: np.ndarray
    origin_height: float = 0.0

    def kept(self, xyz: np.ndarray, finite: np.ndarray | None = None) -> np.ndarray:
        """(N_input,) bool, the input rows that are points: finite (`finite`, when known), and
        returns of an organized layout."""
        finite = finite_rows(xyz) if finite is None else finite
        return finite & returns(xyz) if self.organized is not None else finite

    def rows(self, points: np.ndarray, kept: np.ndarray) -> np.ndarray:
        """(M,) int16 row (0 = top) of a frame's kept points (M, 3), `kept` (N_input,) the mask
        that picked them from the input rows."""
        if self.organized is not None and len(kept) == self.organized.height * self.organized.width:
            return organized_rows(self.organized)[kept]
        return recover_rings(points, self.sensor, self.beams_deg, self.origin_height).ring


@njit(cache=True)
def finite_rows(values):  # pragma: no cover - numba
    """(N,) bool: the rows of (N, C) `values` whose every value is finite."""
    n, c = values.shape
    out = np.ones(n, dtype=np.bool_)
    for i in range(n):
        for k in range(c):
            if not np.isfinite(values[i, k]):
                out[i] = False
                break
    return out


def _elevations(points: np.ndarray, rows: np.ndarray, n_rows: int) -> np.ndarray:
    """(R,) median elevation (degrees) of each row's points at least MIN_RHO from the axis (nearer
    ones are the car, the mount or placeholders: nuScenes puts a quarter of a sweep's points at
    the sensor), NaN for a row without such points."""
    p = points.astype(np.float64)
    rho = np.hypot(p[:, 0], p[:, 1])
    far = rho >= MIN_RHO
    el = np.degrees(np.arctan2(p[far, 2], rho[far]))
    return segment_medians(el, rows[far].astype(np.int64), n_rows)


def measured_sensor(
    name: str, points: np.ndarray, rows: np.ndarray, n_rows: int, width: int | None = None
) -> SensorModel:
    """The sensor of (N, 3) points in `n_rows` known rows (N,): a preset when the rows' median
    elevations match one, else a model `name` of them. `width`: the exact columns of an organized
    layout; None estimates them from the points per row (a preset keeps its own)."""
    if width is not None:
        sensor = sensor_from_elevations(name, _elevations(points, rows, n_rows), width)
        return dataclasses.replace(sensor, width=max(8, width))
    return sensor_from_elevations(name, _elevations(points, rows, n_rows), _per_row_width(points, rows, n_rows))


def _measured_beams(points: np.ndarray, rows: np.ndarray, n_rows: int) -> np.ndarray:
    """(R,) the rows' measured elevations, descending; a row without points interpolated."""
    el = _elevations(points, rows, n_rows)
    have = ~np.isnan(el)
    idx = np.arange(n_rows)
    return np.minimum.accumulate(np.interp(idx, idx[have], el[have]))


def _per_row_width(points: np.ndarray, rows: np.ndarray, n_rows: int) -> int:
    """Columns of one revolution from a scan's points per row (95th percentile: rows lose returns,
    none gains) over the share of the revolution the scan covers (a camera-view crop holds a
    quarter of each row)."""
    per_row = float(np.percentile(np.bincount(rows.astype(np.int64), minlength=n_rows), 95))
    return int(round(per_row / max(azimuth_coverage(points), 1e-3)))


def known_layout(sensor: SensorModel, xyz: np.ndarray) -> Layout:
    """The layout of a sequence whose sensor is given (a flag, metadata): the first frame's (N, 3)
    points only decide whether it is an organized layout of the sensor's beam count."""
    shape = organized_shape(xyz)
    if shape is not None and shape.height != sensor.n_rings:
        shape = None
    return Layout(sensor, "given", shape, np.asarray(sensor.elevations_deg))


def _shown(points: np.ndarray, rows: np.ndarray, n_rows: int) -> bool:
    """Whether at least two rows hold points to measure (beyond MIN_RHO)."""
    return int(np.sum(~np.isnan(_elevations(points, rows, n_rows)))) >= 2


def _organized(xyz: np.ndarray, name: str) -> Layout | None:
    shape = organized_shape(xyz)
    if shape is None:
        return None
    h, w = shape.height, shape.width
    hit = returns(xyz)
    rows = organized_rows(shape)[hit]
    if not _shown(xyz[hit], rows, h):
        return None
    sensor = measured_sensor(f"{name}-{h}beam", xyz[hit], rows, h, w)
    return Layout(sensor, "organized layout", shape, np.asarray(sensor.elevations_deg))


def _scan_order(points: np.ndarray, name: str) -> Layout | None:
    rows, found = scan_order_rings(points, None)
    if rows is None or found < 2 or not _shown(points, rows, found):
        return None
    sensor = measured_sensor(f"{name}-{found}beam", points, rows, found)
    return Layout(sensor, "scan order", None, _measured_beams(points, rows, found))


def _histogram(points: np.ndarray, name: str) -> Layout | None:
    beams = find_beams(points)
    if beams is None:
        return None
    rows = beam_rows(points, beams.elevations_deg, beams.origin_height)
    if not _shown(points, rows, beams.n_beams):
        return None
    el = _elevations(points, rows, beams.n_beams)
    sensor = sensor_from_elevations(f"{name}-{beams.n_beams}beam", el, beams.width)
    return Layout(sensor, "elevation histogram", None, beams.elevations_deg, beams.origin_height)


def detect_layout(xyz: np.ndarray, name: str) -> Layout:
    """The layout and sensor of a sequence from its first frame's (N, 3) points (see the module
    docstring); `name` prefixes the name of a sensor that matches no preset."""
    layout = _organized(xyz, name)
    if layout is not None:
        return layout
    points = np.ascontiguousarray(xyz[np.isfinite(xyz).all(axis=1)], dtype=np.float32)
    layout = _scan_order(points, name) or _histogram(points, name)
    if layout is not None:
        return layout
    sensor = PRESETS[DEFAULT_SENSOR]
    return Layout(sensor, "default", None, np.asarray(sensor.elevations_deg))
