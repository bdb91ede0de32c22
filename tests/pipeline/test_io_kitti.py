from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from pipeline.errors import DataError
from pipeline.io import open_reader
from pipeline.io.kitti import KittiSequence
from pipeline.io.semantickitti import (
    read_bin,
    write_bin,
    write_calib_identity,
    write_label,
    write_poses,
    write_times,
)
from pipeline.scan import SequenceSource
from tests.pipeline.test_rings import beam_scan


def pose(x: float, yaw: float = 0.0) -> np.ndarray:
    t = np.eye(4)
    t[:2, :2] = [[np.cos(yaw), -np.sin(yaw)], [np.sin(yaw), np.cos(yaw)]]
    t[0, 3] = x
    return t


def write_sequence(
    root: Path,
    frames: int = 3,
    sensor: str | None = "hdl32e",
    labels: bool = True,
    poses: bool = True,
    cols: int = 360,
) -> Path:
    """A small simulated-like SemanticKITTI folder written with the semantickitti writers."""
    (root / "velodyne").mkdir(parents=True)
    if labels:
        (root / "labels").mkdir()
    for i in range(frames):
        pts, rows = beam_scan(sensor or "hdl64e", cols=cols, seed=i)
        write_bin(root / "velodyne" / f"{i:06d}.bin", pts, np.linspace(0, 1, len(pts), dtype=np.float32))
        if labels:
            semantic = np.where(rows > 20, 40, 10).astype(np.uint16)  # ground low, car above
            write_label(root / "labels" / f"{i:06d}.label", semantic, (rows == 3).astype(np.uint16) * 7)
    if poses:
        write_poses(root / "poses.txt", np.stack([pose(0.5 * i, 0.01 * i) for i in range(frames)]))
        write_calib_identity(root / "calib.txt")
        write_times(root / "times.txt", 0.1 * np.arange(frames))
    if sensor is not None:
        (root / "metadata.json").write_text(json.dumps({"sensor": sensor, "seed": 0}))
    return root


def test_kitti_round_trip_points_labels_poses(tmp_path: Path) -> None:
    root = write_sequence(tmp_path / "seq")
    seq = open_reader(root)
    assert isinstance(seq, SequenceSource) and seq.format == "kitti"
    assert len(seq) == 3 and seq.frame_name(1) == "000001"
    assert seq.sensor.name == "hdl32e"
    pts, rows = beam_scan("hdl32e", cols=360, seed=1)
    scan = seq.frame(1)
    np.testing.assert_array_equal(scan.points, pts)
    np.testing.assert_array_equal(scan.ring, rows)
    assert scan.intensity.dtype == np.float32 and scan.intensity.max() <= 1.0
    np.testing.assert_array_equal(scan.semantic, np.where(rows > 20, 40, 10))
    assert scan.instance.dtype == np.uint16 and scan.instance.max() == 7
    np.testing.assert_allclose(seq.poses[2], pose(1.0, 0.02), atol=1e-8)
    np.testing.assert_allclose(seq.times, [0.0, 0.1, 0.2])


def test_kitti_auto_sensor_from_ring_count(tmp_path: Path) -> None:
    root = write_sequence(tmp_path / "seq", sensor=None, labels=False, poses=False)
    seq = KittiSequence(root)  # beam_scan(hdl64e): 64 rings in scan order
    assert seq.sensor.name == "hdl64e" and seq.poses is None and seq.times is None


def test_kitti_auto_sensor_vlp16_by_ring_count(tmp_path: Path) -> None:
    (tmp_path / "velodyne").mkdir()
    pts, rows = beam_scan("vlp16", cols=360)
    write_bin(tmp_path / "velodyne" / "000000.bin", pts, np.zeros(len(pts), np.float32))
    seq = KittiSequence(tmp_path)
    assert seq.sensor.name == "vlp16"
    np.testing.assert_array_equal(seq.frame(0).ring, rows)


def test_kitti_nan_rows_dropped_and_labels_aligned(tmp_path: Path) -> None:
    root = write_sequence(tmp_path / "seq", frames=1, poses=False)
    f = root / "velodyne" / "000000.bin"
    raw = read_bin(f).copy()
    raw[[5, 9], 0] = np.nan
    raw[11, 3] = np.inf
    raw.tofile(f)
    scan = KittiSequence(root).frame(0)
    assert scan.dropped == 3 and len(scan) == len(raw) - 3
    _, rows = beam_scan("hdl32e", cols=360, seed=0)
    keep = np.ones(len(raw), bool)
    keep[[5, 9, 11]] = False
    np.testing.assert_array_equal(scan.semantic, np.where(rows[keep] > 20, 40, 10))


def test_kitti_single_bin_file_reads_sibling_label(tmp_path: Path) -> None:
    root = write_sequence(tmp_path / "seq", frames=2)
    seq = open_reader(root / "velodyne" / "000001.bin")
    assert len(seq) == 1 and seq.poses is None and seq.frame_name(0) == "000001"
    assert seq.frame(0).semantic is not None


def test_kitti_poses_apply_calib_tr(tmp_path: Path) -> None:
    root = write_sequence(tmp_path / "seq", frames=2, labels=False)
    tr = pose(0.3, 0.5)
    tr[2, 3] = -0.1
    (root / "calib.txt").write_text("Tr: " + " ".join(f"{v:.12e}" for v in tr[:3].ravel()) + "\n")
    cam = np.stack([pose(0.0), pose(2.0, 0.1)])
    write_poses(root / "poses.txt", cam)
    seq = KittiSequence(root)
    np.testing.assert_allclose(seq.poses[1], np.linalg.inv(tr) @ cam[1] @ tr, atol=1e-8)


def test_kitti_poses_with_time_column(tmp_path: Path) -> None:
    root = write_sequence(tmp_path / "seq", frames=2, labels=False)
    (root / "times.txt").unlink()
    lines = [f"{0.5 + i} " + " ".join(f"{v:.9e}" for v in pose(float(i))[:3].ravel()) for i in range(2)]
    (root / "poses.txt").write_text("\n".join(lines) + "\n")
    seq = KittiSequence(root)
    np.testing.assert_allclose(seq.times, [0.5, 1.5])
    np.testing.assert_allclose(seq.poses[1][0, 3], 1.0)


def test_kitti_explicit_poses_file(tmp_path: Path) -> None:
    root = write_sequence(tmp_path / "seq", frames=2, poses=False, labels=False)
    write_poses(tmp_path / "other.txt", np.stack([pose(0.0), pose(3.0)]))
    seq = open_reader(root, poses=tmp_path / "other.txt")
    np.testing.assert_allclose(seq.poses[1][0, 3], 3.0)


def test_kitti_poses_count_mismatch_names_file(tmp_path: Path) -> None:
    root = write_sequence(tmp_path / "seq", frames=3)
    write_poses(root / "poses.txt", np.stack([pose(0.0), pose(1.0)]))
    with pytest.raises(DataError, match="poses.txt: has 2 poses but the sequence has 3 frames"):
        KittiSequence(root)


def test_kitti_label_count_mismatch_names_file(tmp_path: Path) -> None:
    root = write_sequence(tmp_path / "seq", frames=1, poses=False)
    write_label(root / "labels" / "000000.label", np.zeros(10, np.uint16), np.zeros(10, np.uint16))
    with pytest.raises(DataError, match="000000.label: has 10 labels"):
        KittiSequence(root).frame(0)


def test_kitti_truncated_bin_names_file(tmp_path: Path) -> None:
    root = write_sequence(tmp_path / "seq", frames=1, poses=False, labels=False)
    f = root / "velodyne" / "000000.bin"
    f.write_bytes(f.read_bytes()[:-6])
    with pytest.raises(DataError, match="000000.bin: size"):
        KittiSequence(root).frame(0)


def test_kitti_empty_velodyne_folder(tmp_path: Path) -> None:
    (tmp_path / "velodyne").mkdir()
    with pytest.raises(DataError, match="holds no .bin scans"):
        KittiSequence(tmp_path)


def test_kitti_metadata_unknown_sensor_names_file(tmp_path: Path) -> None:
    root = write_sequence(tmp_path / "seq", frames=1, sensor="hdl32e")
    (root / "metadata.json").write_text(json.dumps({"sensor": "hdl99"}))
    with pytest.raises(DataError, match="metadata.json"):
        KittiSequence(root)


def test_kitti_seq09_real_poses_and_rings(kitti_seq09: Path) -> None:
    seq = open_reader(kitti_seq09)
    assert len(seq) == 5 and seq.sensor.name == "hdl64e"
    assert seq.poses.shape == (5, 4, 4)
    steps = [
        np.linalg.norm((np.linalg.inv(a) @ b)[:3, 3])
        for a, b in zip(seq.poses[:-1], seq.poses[1:], strict=True)
    ]
    assert all(0.37 < s < 0.43 for s in steps), steps  # SOURCES.md: 0.38-0.41 m per frame
    scan = seq.frame(0)
    assert 120_000 < len(scan) < 130_000 and scan.dropped == 0
    assert set(np.unique(scan.ring)) == set(range(64))
    assert scan.intensity.min() >= 0.0 and scan.intensity.max() <= 1.0


def test_kitti_real_single_file(real_data: Path) -> None:
    seq = open_reader(real_data / "kitti_seq09" / "velodyne" / "000003.bin")
    assert len(seq) == 1 and seq.sensor.name == "hdl64e"
    assert len(seq.frame(0)) == 2027200 // 16


def test_kitti_corrupt_first_frame_opens_and_names_it_when_read(tmp_path: Path) -> None:
    """The sensor and layout come from the first frame that reads; the corrupt one fails alone."""
    root = write_sequence(tmp_path / "seq", frames=3, sensor=None, labels=False, cols=100)
    bad = root / "velodyne" / "000000.bin"
    bad.write_bytes(bad.read_bytes()[:-3])
    seq = KittiSequence(root)
    assert seq.sensor.name == "hdl64e" and len(seq.frame(1)) == 6400
    with pytest.raises(DataError, match="000000.bin"):
        seq.frame(0)


def test_kitti_folder_frames_in_natural_order(tmp_path: Path) -> None:
    (tmp_path / "velodyne").mkdir()
    for i in range(11):
        pts, _ = beam_scan("hdl32e", cols=100, seed=i)
        write_bin(tmp_path / "velodyne" / f"{i}.bin", pts, np.zeros(len(pts), np.float32))
    seq = KittiSequence(tmp_path)
    assert [seq.frame_name(k) for k in range(11)] == [str(i) for i in range(11)]
