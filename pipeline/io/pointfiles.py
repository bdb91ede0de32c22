"""PCD (via pypcd4) and PLY (via plyfile) point clouds: one file, or a folder of files = a sequence.

Fields are matched by name (case-insensitive):

- `x`, `y`, `z` (required), in the lidar frame;
- intensity: `intensity`, `remission`, `reflectivity`, `i`, `scalar_intensity`. Integers are
  divided by their type's maximum; floats are kept when the first frame's maximum is <= 1, divided
  by 255 when it is <= 255, else by 65535 (then clipped to [0, 1]). Absent = 0;
- ring: `ring`, `laser_id`, `channel`, `ring_id`, `scalar_ring`. Its direction is taken from the
  elevation (Velodyne drivers number from the bottom, Ouster from the top). Without one, an
  organised cloud (PCD `HEIGHT` > 1) gives one ring per row; otherwise the first frame decides
  (`pipeline.io.layout`: an organized H x W layout of zeros for no return, scan order, the
  elevation histogram of an unordered cloud);
- time: `t`, `time`, `timestamp`, `ts`, made relative to the scan's first point; integers, and
  floats spanning more than a second, are taken as nanoseconds;
- labels: `label` (uint32, SemanticKITTI layout).

The sensor ("auto") is the preset whose beams match the first frame's rings (count and
elevations within 1 deg), or a model of that frame's per-ring median elevations; HDL-64E when no
beams show. A folder's files are frames in the natural order of their names (`2.pcd` before
`10.pcd`), named NNNNNN after the number of their name (`7.pcd` is frame `000007`), or after
their place when a name holds anything but digits. A folder may hold poses as a KITTI sequence
does (`poses.txt`, 12 or 13 numbers a line, with `calib.txt`'s `Tr`, else taken as
T_world_lidar; `times.txt`), or take a poses file (and calib) by argument.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from pipeline.errors import DataError
from pipeline.io.layout import Layout, detect_layout, known_layout, measured_sensor
from pipeline.io.registry import frame_files
from pipeline.io.rings import rows_from_ring_field
from pipeline.io.semantickitti import folder_poses
from pipeline.scan import Scan, input_rows_of
from pipeline.sensors import SensorModel, get_sensor

INTENSITY_FIELDS = ("intensity", "remission", "reflectivity", "i", "scalar_intensity")
RING_FIELDS = ("ring", "laser_id", "channel", "ring_id", "scalar_ring")
TIME_FIELDS = ("t", "time", "timestamp", "ts")


def _field(table: np.ndarray, names: tuple[str, ...]) -> np.ndarray | None:
    lower = {n.lower(): n for n in table.dtype.names or ()}
    for name in names:
        if name in lower:
            return table[lower[name]]
    return None


def _intensity_scale(values: np.ndarray) -> float:
    if np.issubdtype(values.dtype, np.integer):
        return float(np.iinfo(values.dtype).max)
    finite = values[np.isfinite(values)]
    top = float(finite.max()) if len(finite) else 0.0
    return 1.0 if top <= 1.0 else 255.0 if top <= 255.0 else 65535.0


def _relative_time(values: np.ndarray) -> np.ndarray:
    t = values.astype(np.float64)
    t = t - t.min() if len(t) else t
    if np.issubdtype(values.dtype, np.integer) or (len(t) and t.max() > 1.0):
        t = t * 1e-9
    return t.astype(np.float32)


def _frame_names(files: list[Path], suffix: str) -> list[str]:
    """NNNNNN per file: the number its name holds (`7.pcd` -> `000007`), or its place in the
    sequence when any name holds anything but digits (or two numbers are equal)."""
    stems = [f.name[: -len(suffix)] for f in files]
    if all(s.isdigit() for s in stems) and len({int(s) for s in stems}) == len(stems):
        return [f"{int(s):06d}" for s in stems]
    return [f"{i:06d}" for i in range(len(files))]


class _PointFileSequence:
    """Files of one suffix read lazily as a `pipeline.scan.SequenceSource` without poses."""

    format = ""
    suffix = ""

    def __init__(
        self,
        path: str | Path,
        sensor: str | SensorModel = "auto",
        poses: str | Path | None = None,
        calib: str | Path | None = None,
    ) -> None:
        self.path = Path(path)
        self._files = self._list_files()
        self._names = _frame_names(self._files, self.suffix)
        self.warnings: list[str] = []
        root = self.path if self.path.is_dir() else self.path.parent
        self.poses, self.times = folder_poses(self.path, root, len(self._files), poses, calib, self.warnings)
        first = self._table(0)
        intensity = _field(first[0], INTENSITY_FIELDS)
        self._intensity_scale = 1.0 if intensity is None else _intensity_scale(intensity)
        if intensity is None:
            self.warnings.append(f"{self._files[0]}: no intensity field, intensity set to 0")
        self._layout: Layout | None = None  # None: rows come from a ring field or the PCD's rows
        self.sensor = self._pick_sensor(sensor, first)

    def _list_files(self) -> list[Path]:
        if self.path.is_file():
            return [self.path]
        if not self.path.is_dir():
            raise DataError(self.path, "no such file or folder")
        files = frame_files(self.path.glob(f"*{self.suffix}"))
        if not files:
            raise DataError(self.path, f"holds no {self.suffix} files")
        return files

    def _read_table(self, path: Path) -> tuple[np.ndarray, int]:
        """(structured array (N,), rows of an organised cloud or 1)."""
        raise NotImplementedError

    def _table(self, index: int) -> tuple[np.ndarray, int]:
        path = self._files[index]
        try:
            table, height = self._read_table(path)
        except DataError:
            raise
        except Exception as exc:  # parsers raise many types on corrupt files
            raise DataError(path, f"cannot read {self.format.upper()}: {exc}") from None
        if table.dtype.names is None or not {"x", "y", "z"} <= {n.lower() for n in table.dtype.names}:
            raise DataError(path, "needs x, y and z fields")
        return table, height

    def _xyz(self, table: np.ndarray) -> np.ndarray:
        return np.column_stack([_field(table, (c,)).astype(np.float32) for c in "xyz"])

    def _ring_source(self, table: np.ndarray, height: int) -> np.ndarray | None:
        ring = _field(table, RING_FIELDS)
        if ring is not None:
            return ring.astype(np.int64)
        if height > 1:
            return np.arange(len(table)) // (len(table) // height)
        return None

    def _pick_sensor(self, sensor: str | SensorModel, first: tuple[np.ndarray, int]) -> SensorModel:
        """The flag's sensor, else the one the first frame shows; sets how rows are read."""
        table, height = first
        xyz = self._xyz(table)
        ring = self._ring_source(table, height)
        given = None
        if isinstance(sensor, SensorModel) or sensor != "auto":
            given = sensor if isinstance(sensor, SensorModel) else get_sensor(sensor)
            self.sensor_from = "user flag"
        if ring is not None:
            if given is not None:
                return given
            self.sensor_from = "ring field" if _field(table, RING_FIELDS) is not None else "organized layout"
            finite = np.isfinite(xyz).all(axis=1)
            n = int(ring[finite].max()) + 1 if finite.any() else 0
            if n < 2:
                raise DataError(self._files[0], f"the ring field shows {n} rings")
            rows = rows_from_ring_field(xyz[finite], ring[finite], n)
            width = len(table) // height if height > 1 else None
            return measured_sensor(f"{self.format}-{n}beam", xyz[finite], rows, n, width)
        if given is not None:
            self._layout = known_layout(given, xyz)
            return given
        self._layout = detect_layout(xyz, self.format)
        self.sensor_from = self._layout.how
        if self._layout.how == "default":
            self.warnings.append(
                f"{self._files[0]}: no ring field and no beams show; rows use {self._layout.sensor.name} elevations"
            )
        return self._layout.sensor

    def __len__(self) -> int:
        return len(self._files)

    def frame_name(self, index: int) -> str:
        return self._names[index]

    def frame(self, index: int) -> Scan:
        table, height = self._table(index)
        xyz = self._xyz(table)
        intensity = _field(table, INTENSITY_FIELDS)
        time = _field(table, TIME_FIELDS)
        columns = [xyz]
        if intensity is not None:
            columns.append(intensity.astype(np.float64)[:, None])
        if time is not None and np.issubdtype(time.dtype, np.floating):
            columns.append(time[:, None])
        finite = np.isfinite(np.column_stack(columns)).all(axis=1)
        kept = finite if self._layout is None else finite & self._layout.kept(xyz)
        points = np.ascontiguousarray(xyz[kept])
        if self._layout is None:
            ring = self._ring_source(table, height)
            assert ring is not None
            rows = rows_from_ring_field(points, ring[kept], self.sensor.n_rings)
        else:
            rows = self._layout.rows(points, kept)
        if intensity is None:
            inten = np.zeros(len(points), np.float32)
        else:
            inten = np.clip(intensity[kept] / self._intensity_scale, 0.0, 1.0).astype(np.float32)
        label = _field(table, ("label",))
        semantic = instance = None
        if label is not None:
            raw = label[kept].astype(np.uint32)
            semantic, instance = (raw & 0xFFFF).astype(np.uint16), (raw >> 16).astype(np.uint16)
        return Scan(
            points=points,
            intensity=inten,
            ring=rows,
            time=None if time is None else _relative_time(time[kept]),
            semantic=semantic,
            instance=instance,
            dropped=int(len(finite) - finite.sum()),
            input_rows=input_rows_of(kept),
        )


class PcdSequence(_PointFileSequence):
    """`.pcd` files read with pypcd4."""

    format = "pcd"
    suffix = ".pcd"

    def _read_table(self, path: Path) -> tuple[np.ndarray, int]:
        from pypcd4 import PointCloud

        pc = PointCloud.from_path(path)
        return pc.pc_data, int(pc.metadata.height)


class PlySequence(_PointFileSequence):
    """`.ply` files read with plyfile (the `vertex` element)."""

    format = "ply"
    suffix = ".ply"

    def _read_table(self, path: Path) -> tuple[np.ndarray, int]:
        from plyfile import PlyData

        ply = PlyData.read(str(path))
        if "vertex" not in [e.name for e in ply.elements]:
            raise DataError(path, "has no vertex element")
        return np.asarray(ply["vertex"].data), 1
