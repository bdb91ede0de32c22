"""Typed scans and sequences: the data boundary of the library.

Frames: points are in the lidar frame (x forward, y left, z up, metres).
`T_world_lidar` (4, 4) maps lidar points to the world: p_world = T_world_lidar @ p_lidar.

A scan holds only usable points: readers drop input rows with NaN or inf, and the pixels without
a return of an organized H x W layout. `Scan.input_rows` remembers which input rows became points,
so that every per-point output can be written back with one value per input row
(`Scan.to_input`; docs/conventions.md, "One value per input point").
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Protocol, runtime_checkable

import numpy as np

from pipeline.sensors import SensorModel


@dataclass(frozen=True)
class Scan:
    """One LiDAR revolution.

    points:    (N, 3) float32, lidar frame, metres.
    intensity: (N,) float32 in [0, 1].
    ring:      (N,) int16 beam row, 0 = top beam (matches the range-image row).
    time:      (N,) float32 seconds since the start of the scan, or None.
    semantic:  (N,) uint16 SemanticKITTI semantic id, or None.
    instance:  (N,) uint16 instance id (0 = none), or None.
    dropped:   count of input rows removed because they held NaN or inf.
    input_rows: (N_input,) bool, the input rows that became the points of this scan, in order
               (point k is the k-th True row); None when every input row is a point (N_input = N).
    """

    points: np.ndarray
    intensity: np.ndarray
    ring: np.ndarray
    time: np.ndarray | None = None
    semantic: np.ndarray | None = None
    instance: np.ndarray | None = None
    dropped: int = 0
    input_rows: np.ndarray | None = None

    def __post_init__(self) -> None:
        n = len(self.points)
        assert self.points.ndim == 2 and self.points.shape[1] == 3, self.points.shape
        assert self.points.dtype == np.float32, self.points.dtype
        assert self.intensity.shape == (n,) and self.intensity.dtype == np.float32
        assert self.ring.shape == (n,) and self.ring.dtype == np.int16
        for name in ("time", "semantic", "instance"):
            arr = getattr(self, name)
            assert arr is None or arr.shape == (n,), (name, None if arr is None else arr.shape, n)
        rows = self.input_rows
        assert rows is None or (rows.ndim == 1 and rows.dtype == np.bool_ and int(rows.sum()) == n)

    def __len__(self) -> int:
        return len(self.points)

    @property
    def n_input(self) -> int:
        """Rows of the input this scan was read from (points plus dropped rows)."""
        return len(self.points) if self.input_rows is None else len(self.input_rows)

    def to_input(self, values: np.ndarray, fill: float | int = 0) -> np.ndarray:
        """(N_input, ...) `values` (N, ...) per point spread back to the input rows; `fill` where
        an input row is not a point (NaN, inf, no return)."""
        values = np.asarray(values)
        assert values.shape[:1] == (len(self),), (values.shape, len(self))
        if self.input_rows is None:
            return values
        out = np.full((self.n_input, *values.shape[1:]), fill, dtype=values.dtype)
        out[self.input_rows] = values
        return out

    @property
    def has_labels(self) -> bool:
        return self.semantic is not None

    def select(self, mask: np.ndarray) -> Scan:
        """The scan restricted to the points where `mask` (N,) bool is true."""

        def pick(a: np.ndarray | None) -> np.ndarray | None:
            return None if a is None else a[mask]

        return Scan(
            self.points[mask],
            self.intensity[mask],
            self.ring[mask],
            pick(self.time),
            pick(self.semantic),
            pick(self.instance),
            self.dropped,
            self._input_rows_after(mask),
        )

    def _input_rows_after(self, mask: np.ndarray) -> np.ndarray:
        """input_rows of `select(mask)`: the input rows of the points kept by `mask`."""
        if self.input_rows is None:
            return np.asarray(mask, dtype=bool).copy()
        rows = self.input_rows.copy()
        rows[self.input_rows] = mask
        return rows


@runtime_checkable
class SequenceSource(Protocol):
    """A LiDAR sequence: frames read lazily, with optional poses, times and labels.

    sensor_from: how the sensor was decided, one of `pipeline.sensors.SENSOR_FROM`.
    poses: (F, 4, 4) float64 `T_world_lidar` per frame, or None when the source has none.
    times: (F,) float64 seconds per frame, or None.
    """

    path: Path
    format: str
    sensor: SensorModel
    sensor_from: str
    poses: np.ndarray | None
    times: np.ndarray | None

    def __len__(self) -> int: ...

    def frame(self, index: int) -> Scan: ...

    def frame_name(self, index: int) -> str: ...


@dataclass
class SequenceInfo:
    """Summary of a sequence, as printed by `tracklabel inspect`."""

    path: Path
    format: str
    sensor: str
    beams: int
    columns: int  # range-image width
    sensor_from: str  # how the sensor was decided (pipeline.sensors.SENSOR_FROM)
    frames: int
    points_min: int
    points_median: float
    points_max: int
    poses: str  # "given" | "absent" | "estimable"
    dropped_rows: int = 0
    class_histogram: dict[str, int] | None = None
    warnings: list[str] = field(default_factory=list)


def iter_frames(source: SequenceSource) -> Iterator[Scan]:
    """Yield every frame of a source in order."""
    for i in range(len(source)):
        yield source.frame(i)


def clean_rows(values: np.ndarray) -> tuple[np.ndarray, int]:
    """Mask (N,) of rows of `values` (N, C) that are all finite, and the number that are not."""
    finite = np.isfinite(values).all(axis=1)
    return finite, int(len(finite) - finite.sum())


def input_rows_of(kept: np.ndarray) -> np.ndarray | None:
    """`Scan.input_rows` for the input-row mask `kept` (N_input,): None when every row is kept."""
    kept = np.asarray(kept, dtype=bool)
    return None if kept.all() else kept
