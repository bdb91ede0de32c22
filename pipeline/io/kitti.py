"""KITTI / SemanticKITTI sequences: `velodyne/*.bin`, optional labels, poses, calib and times.

Layout (a folder, or a single `.bin` as a one-frame sequence)::

    SEQ/velodyne/NNNNNN.bin   float32 (N, 4): x, y, z, remission in [0, 1]
    SEQ/labels/NNNNNN.label   optional, uint32 semantic | instance << 16
    SEQ/poses.txt             optional, camera-0 poses P_k (12 numbers a line, or time + 12)
    SEQ/calib.txt             optional `Tr:` velodyne -> camera; absent = identity
    SEQ/times.txt             optional, one time (s) per frame
    SEQ/metadata.json         optional, {"sensor": "hdl32e", ...} (written by the simulator)

Frames are ordered by the natural order of their names. Poses become lidar poses
`T_world_lidar = inv(Tr) @ P_k @ Tr`. The sensor is, in order: the `sensor` argument,
metadata.json, or what the first frame shows (`pipeline.io.layout`: an organized H x W layout,
scan order, the elevation histogram). Rows come from the organized layout, else scan order, else
the elevations (`pipeline.io.layout.Layout.rows`).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from pipeline.errors import DataError
from pipeline.io.layout import Layout, detect_layout, finite_rows, known_layout
from pipeline.io.registry import frame_files
from pipeline.io.semantickitti import folder_poses, read_bin, read_label
from pipeline.scan import Scan, input_rows_of
from pipeline.sensors import SensorModel, get_sensor


def _scan_files(path: Path) -> tuple[list[Path], Path]:
    """The `.bin` files of a sequence and its root folder."""
    if path.is_file():
        root = path.parent.parent if path.parent.name == "velodyne" else path.parent
        return [path], root
    if not path.is_dir():
        raise DataError(path, "no such file or folder")
    folder = path / "velodyne" if (path / "velodyne").is_dir() else path
    files = frame_files(f for f in folder.glob("*.bin") if not f.name.endswith(".pcd.bin"))
    if not files:
        raise DataError(folder, "holds no .bin scans")
    return files, path


def _metadata_sensor(root: Path) -> SensorModel | None:
    meta = root / "metadata.json"
    if not meta.is_file():
        return None
    try:
        value = json.loads(meta.read_text()).get("sensor")
    except (OSError, json.JSONDecodeError, AttributeError) as exc:
        raise DataError(meta, f"cannot read: {exc}") from None
    if value is None:
        return None
    if isinstance(value, dict):
        return SensorModel.from_dict(value)
    try:
        return get_sensor(str(value))
    except KeyError as exc:
        raise DataError(meta, str(exc.args[0])) from None


class KittiSequence:
    """A KITTI / SemanticKITTI sequence, read lazily frame by frame (`pipeline.scan.SequenceSource`)."""

    format = "kitti"

    def __init__(
        self,
        path: str | Path,
        sensor: str | SensorModel = "auto",
        poses: str | Path | None = None,
        calib: str | Path | None = None,
    ) -> None:
        self.path = Path(path)
        self._files, self.root = _scan_files(self.path)
        labels = self.root / "labels"
        self._labels = labels if labels.is_dir() else None
        self.warnings: list[str] = []
        self.poses, self.times = folder_poses(self.path, self.root, len(self._files), poses, calib, self.warnings)
        self._layout = self._pick_layout(sensor)
        self.sensor = self._layout.sensor

    def _pick_layout(self, sensor: str | SensorModel) -> Layout:
        """The sensor (flag, metadata.json, else found in the first frame) and how rows are read."""
        if isinstance(sensor, SensorModel) or sensor != "auto":
            self.sensor_from = "user flag"
            chosen = sensor if isinstance(sensor, SensorModel) else get_sensor(sensor)
        else:
            chosen = _metadata_sensor(self.root)
            self.sensor_from = "metadata"
        name, first = self._first_readable()
        if chosen is not None:
            return known_layout(chosen, first)
        layout = detect_layout(first, "kitti")
        self.sensor_from = layout.how
        if layout.how == "default":
            self.warnings.append(f"{name}: no beams show in this frame; rows use {layout.sensor.name} elevations")
        return layout

    def _first_readable(self) -> tuple[Path, np.ndarray]:
        """(file, (N, 3) points) of the first of the first three frames that reads; a corrupt
        frame is the pipeline's to skip, the sequence still opens."""
        for f in self._files[:3]:
            try:
                return f, read_bin(f)[:, :3]
            except DataError as exc:
                error = exc
        raise error

    def __len__(self) -> int:
        return len(self._files)

    def frame_name(self, index: int) -> str:
        return self._files[index].stem

    def label_path(self, index: int) -> Path | None:
        if self._labels is None:
            return None
        p = self._labels / f"{self._files[index].stem}.label"
        return p if p.is_file() else None

    def frame(self, index: int) -> Scan:
        if not -len(self) <= index < len(self):
            raise IndexError(f"frame {index} out of range for {len(self)} frames")
        raw = read_bin(self._files[index])
        finite = finite_rows(raw)
        kept = self._layout.kept(raw[:, :3], finite)
        all_kept = bool(kept.all())
        rows = raw if all_kept else raw[kept]
        points = np.ascontiguousarray(rows[:, :3])
        semantic = instance = None
        label = self.label_path(index)
        if label is not None:
            semantic, instance = read_label(label, expected=len(raw))
            if not all_kept:
                semantic, instance = semantic[kept], instance[kept]
        return Scan(
            points=points,
            intensity=np.clip(rows[:, 3], 0.0, 1.0).astype(np.float32),
            ring=self._layout.rows(points, kept),
            semantic=semantic,
            instance=instance,
            dropped=int(len(raw) - finite.sum()),
            input_rows=input_rows_of(kept),
        )
