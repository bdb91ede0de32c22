"""nuScenes LIDAR_TOP sweeps: `.pcd.bin` files, float32 (N, 5) x, y, z, intensity 0..255, ring 0..31.

A single file is a one-frame sequence; a folder of `.pcd.bin` files is a sequence without poses,
ordered by name (nuScenes names end in the sweep's timestamp in microseconds, which become
`times`).

The sensor carries the nuScenes car's box (`NUSCENES_EGO_BOX`): its returns are never segmented.

Two conversions to our conventions (docs/conventions.md):
- nuScenes' lidar frame has x right, y forward; ours has x forward, y left:
  `x_ours = y_nu`, `y_ours = -x_nu`, `z` unchanged.
- nuScenes ring 0 is the lowest beam (measured on the sample sweep: median elevation -30.6 deg for
  ring 0, +10.6 deg for ring 31), so `row = 31 - ring`.
"""

from __future__ import annotations

import dataclasses
import re
from pathlib import Path

import numpy as np

from pipeline.errors import DataError
from pipeline.io.registry import frame_files
from pipeline.io.semantickitti import read_bin
from pipeline.scan import Scan, clean_rows, input_rows_of
from pipeline.sensors import PRESETS, SensorModel, get_sensor

RECORD = 5
N_RINGS = 32
# The nuScenes car (a Renault Zoe, 4.08 x 1.73 x 1.56 m) around its LIDAR_TOP, which sits 0.94 m
# ahead of the rear axle and 1.84 m above the ground, with a margin for the mirrors and the mount:
# its roof and mount return up to 8,000 points of a sweep (every return of the sample sweep within
# 3 m of the axis lies in this box), which became 16-60 tracks a frame.
NUSCENES_EGO_BOX = (-1.8, 2.5, -1.0, 1.0, -2.0, 0.05)
# nuScenes runs its HDL-32E at 20 Hz: about 1,080 points per ring and revolution.
NUSCENES_SENSOR = dataclasses.replace(PRESETS["hdl32e"], width=1080, frequency_hz=20.0, ego_box=NUSCENES_EGO_BOX)
_STAMP = re.compile(r"__(\d{16})\.pcd\.bin$")


def _files(path: Path) -> list[Path]:
    if path.is_file():
        if not path.name.endswith(".pcd.bin"):
            raise DataError(path, "not a nuScenes .pcd.bin file")
        return [path]
    if not path.is_dir():
        raise DataError(path, "no such file or folder")
    files = frame_files(path.glob("*.pcd.bin"))
    if not files:
        raise DataError(path, "holds no .pcd.bin sweeps")
    return files


class NuScenesSequence:
    """nuScenes `.pcd.bin` sweeps as a `pipeline.scan.SequenceSource` (no poses)."""

    format = "nuscenes"

    def __init__(self, path: str | Path, sensor: str | SensorModel = "auto") -> None:
        self.path = Path(path)
        self._files = _files(self.path)
        self.sensor_from = "ring field" if sensor == "auto" else "user flag"
        if isinstance(sensor, SensorModel):
            self.sensor = sensor
        else:
            self.sensor = NUSCENES_SENSOR if sensor == "auto" else get_sensor(sensor)
        if not self.sensor.ego_box:  # whichever beams the user names, the car is nuScenes'
            self.sensor = dataclasses.replace(self.sensor, ego_box=NUSCENES_EGO_BOX)
        if self.sensor.n_rings != N_RINGS:
            raise DataError(
                self.path,
                f"nuScenes sweeps have 32 rings; sensor {self.sensor.name} has {self.sensor.n_rings}",
            )
        self.poses: np.ndarray | None = None
        stamps = [_STAMP.search(f.name) for f in self._files]
        self.times = np.array([int(m.group(1)) * 1e-6 for m in stamps]) if all(stamps) else None

    def __len__(self) -> int:
        return len(self._files)

    def frame_name(self, index: int) -> str:
        return self._files[index].name[: -len(".pcd.bin")]

    def frame(self, index: int) -> Scan:
        path = self._files[index]
        raw = read_bin(path, record=RECORD)
        finite, dropped = clean_rows(raw)
        rows = raw[finite]
        ring = rows[:, 4]
        if len(ring) and (ring.min() < 0 or ring.max() > N_RINGS - 1 or np.any(ring != np.round(ring))):
            raise DataError(path, f"ring field holds values outside the integers 0..{N_RINGS - 1}")
        points = np.empty((len(rows), 3), dtype=np.float32)
        points[:, 0] = rows[:, 1]
        points[:, 1] = -rows[:, 0]
        points[:, 2] = rows[:, 2]
        return Scan(
            points=points,
            intensity=np.clip(rows[:, 3] / 255.0, 0.0, 1.0).astype(np.float32),
            ring=(N_RINGS - 1 - ring.astype(np.int64)).astype(np.int16),
            dropped=dropped,
            input_rows=input_rows_of(finite),
        )
