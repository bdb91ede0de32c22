"""The one way to open a sequence for the pipeline: reader, sensor, range-image width and poses.

`tracklabel process`, `predict`, the experiments and the service's ingest all call
`open_sequence`, so one recording gets one range image and one set of poses whoever runs it:

1. **reader**: `pipeline.io.open_reader` by format (detected unless named), told the sensor when
   the user names one, so that its rows follow that sensor's beams;
2. **sensor**: the flag's preset or Ouster json, else what the reader decided (metadata, a ring
   field, an organized layout, scan order, the elevation histogram; `Sequence.sensor_from`);
3. **width**: fitted to the first readable frame's points per beam and the share of the
   revolution it covers (`fit_width`) unless the data states it (metadata, an organized layout,
   an Ouster json);
4. **intensity**: the first readable frame's intensity quantiles go with the sensor
   (`pipeline.intensity`: samples show each point's rank among them);
5. **poses**: `file` (the sequence's own, None without) or `icp` (estimated, `pipeline.odometry`).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pipeline.errors import DataError
from pipeline.intensity import measure as measure_intensity
from pipeline.io import open_reader
from pipeline.io.beams import MIN_RHO, azimuth_coverage
from pipeline.progress import QUIET, Progress
from pipeline.scan import Scan, SequenceSource
from pipeline.sensors import SensorModel

POSES = ("file", "icp")
# Decisions that state the columns: an organized layout has W, metadata (the simulator's, an
# Ouster json) names the mode; a width fitted to their points would only count missing returns.
WIDTH_STATED = frozenset({"metadata", "organized layout"})


@dataclass(frozen=True)
class Sequence:
    """An opened sequence, ready for `SequenceProcessor.iter_frames(seq.source, poses=seq.poses)`.

    sensor:      the sensor with its fitted width (range image: sensor.n_rings x sensor.width).
    sensor_from: how it was decided (`pipeline.sensors.SENSOR_FROM`).
    poses:       (F, 4, 4) float64 `T_world_lidar`, or None (frames are not linked).
    pose_source: "file", "icp" or "none".
    """

    source: SequenceSource
    sensor: SensorModel
    sensor_from: str
    poses: np.ndarray | None
    pose_source: str

    def __len__(self) -> int:
        return len(self.source)

    @property
    def format(self) -> str:
        return self.source.format


def fit_width(scan: Scan, sensor: SensorModel) -> SensorModel:
    """The sensor with its range-image width fitted to the scan's points per ring.

    A sensor spinning faster than its preset (nuScenes runs the HDL-32E at 20 Hz) gives fewer
    points per ring; a too-wide image would leave every other column empty and cut every object
    into slivers. Rings lose returns (sky) but never gain any, so the 95th percentile of the
    points per ring counts the columns of the part of the revolution the scan covers, and over
    that share (`azimuth_coverage`: KITTI's camera-view crop holds a quarter of a turn) the
    columns of a revolution; points within MIN_RHO of the axis are left out (the car, and the
    placeholders nuScenes writes for missing returns, a quarter of a sweep).
    """
    if len(scan) == 0:
        return sensor
    xy = scan.points[:, :2].astype(np.float64)  # float64: float32's largest values overflow hypot
    far = (np.hypot(xy[:, 0], xy[:, 1]) >= MIN_RHO) & (scan.ring >= 0)
    per_ring = np.bincount(scan.ring[far].astype(np.int64), minlength=sensor.n_rings)
    most = int(np.percentile(per_ring, 95) / max(azimuth_coverage(scan.points[far]), 1e-3))
    if most >= 0.75 * sensor.width or most < 64:
        return sensor
    width = int(np.ceil(most * 1.005))
    return dataclasses.replace(sensor, width=width, frequency_hz=sensor.frequency_hz * sensor.width / width)


def _first_scan(source: SequenceSource) -> Scan | None:
    """The first of the first three frames that reads, None when none does (the pipeline skips
    corrupt frames; the sequence still opens)."""
    for i in range(min(len(source), 3)):
        try:
            return source.frame(i)
        except DataError:
            continue
    return None


def with_intensity(scan: Scan | None, sensor: SensorModel) -> SensorModel:
    """The sensor with the intensity quantiles of `scan` (`pipeline.intensity.measure`)."""
    if scan is None:
        return sensor
    return dataclasses.replace(sensor, intensity_quantiles=measure_intensity(scan.points, scan.intensity))


def _poses(source: SequenceSource, poses: str, progress: Progress) -> np.ndarray | None:
    if poses == "file":
        return source.poses
    from pipeline.odometry import estimate_poses

    return estimate_poses(source, progress=progress)


def open_sequence(
    path: str | Path, fmt: str = "auto", sensor: str = "auto", poses: str = "file", progress: Progress = QUIET
) -> Sequence:
    """Open `path` (see the module docstring). sensor: auto, a preset name or an Ouster json;
    poses: file or icp. DataError names the path or the bad value."""
    if poses not in POSES:
        raise DataError(None, f"poses must be 'file' or 'icp', got {poses!r}")
    options = {} if sensor == "auto" else {"sensor": sensor}
    source = open_reader(path, fmt, **options)
    if len(source) == 0:
        raise DataError(path, "sequence has no frames")
    stated = source.sensor_from in WIDTH_STATED or str(sensor).endswith(".json")
    first = _first_scan(source)
    fitted = source.sensor if stated or first is None else fit_width(first, source.sensor)
    fitted = with_intensity(first, fitted)
    pose_arr = _poses(source, poses, progress)
    origin = "none" if pose_arr is None else poses
    return Sequence(source, fitted, source.sensor_from, pose_arr, origin)
