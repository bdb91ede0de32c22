from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from pipeline.errors import DataError
from pipeline.inspection import inspect_sequence
from pipeline.io.semantickitti import read_bin
from tests.pipeline.test_io_kitti import write_sequence
from tests.pipeline.test_rings import beam_scan


def test_inspect_sequence_labelled_folder(tmp_path: Path) -> None:
    root = write_sequence(tmp_path / "seq", frames=3, cols=100)
    info = inspect_sequence(root)
    assert (info.format, info.sensor, info.frames, info.poses) == ("kitti", "hdl32e", 3, "given")
    assert info.points_min == info.points_max == 3200 and info.points_median == 3200
    _, rows = beam_scan("hdl32e", cols=100)
    assert info.class_histogram["ground"] == 3 * int((rows > 20).sum())
    assert info.class_histogram["car"] == 3 * int((rows <= 20).sum())
    assert info.class_histogram["unlabelled"] == 0 and info.warnings == []


def test_inspect_sequence_without_poses_is_estimable(tmp_path: Path) -> None:
    info = inspect_sequence(write_sequence(tmp_path / "seq", frames=2, poses=False, labels=False))
    assert info.poses == "estimable" and info.class_histogram is None


def test_inspect_sequence_single_frame_poses_absent(tmp_path: Path) -> None:
    root = write_sequence(tmp_path / "seq", frames=1, poses=False, labels=False)
    assert inspect_sequence(root / "velodyne" / "000000.bin").poses == "absent"


def test_inspect_sequence_counts_dropped_rows(tmp_path: Path) -> None:
    root = write_sequence(tmp_path / "seq", frames=2, poses=False, labels=False)
    f = root / "velodyne" / "000001.bin"
    raw = read_bin(f).copy()
    raw[:4, 2] = np.nan
    raw.tofile(f)
    info = inspect_sequence(root)
    assert info.dropped_rows == 4 and info.points_min == len(raw) - 4
    assert any("4 rows with NaN or inf" in w for w in info.warnings)


def test_inspect_sequence_unknown_folder(tmp_path: Path) -> None:
    (tmp_path / "notes.txt").write_text("hi")
    with pytest.raises(DataError, match="unknown folder layout"):
        inspect_sequence(tmp_path)


def test_inspect_sequence_real_kitti(kitti_seq09: Path) -> None:
    info = inspect_sequence(kitti_seq09)
    assert (info.format, info.sensor, info.frames, info.poses) == ("kitti", "hdl64e", 5, "given")
    assert 120_000 < info.points_min <= info.points_max < 130_000


def test_inspect_sequence_real_nuscenes(real_data: Path) -> None:
    info = inspect_sequence(real_data / "nuscenes_hdl32e")
    assert (info.format, info.frames, info.points_max, info.poses) == ("nuscenes", 1, 34_688, "absent")
