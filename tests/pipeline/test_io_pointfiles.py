from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from plyfile import PlyData, PlyElement
from pypcd4 import Encoding, PointCloud

from pipeline.errors import DataError
from pipeline.io import open_reader
from pipeline.io.pointfiles import PcdSequence, PlySequence
from pipeline.io.semantickitti import pack_label, write_poses
from tests.pipeline.test_rings import beam_scan


def write_pcd(path: Path, columns: dict[str, np.ndarray], height: int = 1) -> Path:
    names = tuple(columns)
    pc = PointCloud.from_points(list(columns.values()), names, tuple(v.dtype.type for v in columns.values()))
    if height > 1:
        pc.metadata.height = height
        pc.metadata.width = len(next(iter(columns.values()))) // height
    pc.save(path, encoding=Encoding.BINARY_COMPRESSED)
    return path


def write_ply(path: Path, columns: dict[str, np.ndarray]) -> Path:
    n = len(next(iter(columns.values())))
    table = np.empty(n, dtype=[(k, v.dtype) for k, v in columns.items()])
    for k, v in columns.items():
        table[k] = v
    PlyData([PlyElement.describe(table, "vertex")]).write(str(path))
    return path


def xyz_columns(points: np.ndarray) -> dict[str, np.ndarray]:
    return {c: np.ascontiguousarray(points[:, i]) for i, c in enumerate("xyz")}


def test_pcd_ring_field_bottom_first_and_uint8_intensity(tmp_path: Path) -> None:
    pts, rows = beam_scan("hdl32e", cols=90)
    cols = xyz_columns(pts)
    cols["intensity"] = np.full(len(pts), 51, np.uint8)
    cols["ring"] = (31 - rows).astype(np.uint16)  # Velodyne driver numbering: 0 = lowest beam
    seq = open_reader(write_pcd(tmp_path / "a.pcd", cols))
    assert seq.format == "pcd" and seq.sensor.name == "hdl32e"
    scan = seq.frame(0)
    np.testing.assert_array_equal(scan.ring, rows)
    np.testing.assert_allclose(scan.intensity, 0.2)


def test_pcd_without_ring_recovers_scan_order(tmp_path: Path) -> None:
    pts, rows = beam_scan("vlp16", cols=200)
    cols = xyz_columns(pts)
    cols["intensity"] = np.linspace(0, 200, len(pts)).astype(np.float32)
    seq = PcdSequence(write_pcd(tmp_path / "a.pcd", cols))
    assert seq.sensor.name == "vlp16"
    scan = seq.frame(0)
    np.testing.assert_array_equal(scan.ring, rows)
    assert scan.intensity.max() == pytest.approx(200 / 255)


def test_pcd_organised_cloud_rows_are_rings(tmp_path: Path) -> None:
    pts, rows = beam_scan("hdl32e", cols=64)
    perm = np.random.default_rng(0).permutation(64)  # columns out of azimuth order
    grid = pts.reshape(32, 64, 3)[:, perm].reshape(-1, 3)
    grid[5] = np.nan  # a missing return
    scan = PcdSequence(write_pcd(tmp_path / "o.pcd", xyz_columns(grid), height=32)).frame(0)
    assert scan.dropped == 1
    np.testing.assert_array_equal(scan.ring, np.delete(rows, 5))


def test_pcd_unknown_beam_count_builds_sensor(tmp_path: Path) -> None:
    pts, rows = beam_scan("hdl32e", cols=90)
    keep = rows < 24  # a 24-beam sensor: no preset
    cols = xyz_columns(pts[keep])
    cols["ring"] = rows[keep].astype(np.uint16)
    seq = PcdSequence(write_pcd(tmp_path / "a.pcd", cols))
    assert seq.sensor.n_rings == 24 and seq.sensor.name == "pcd-24beam"
    assert seq.sensor.elevations_deg[0] == pytest.approx(10.67, abs=0.01)


def test_pcd_time_and_label_fields(tmp_path: Path) -> None:
    pts, rows = beam_scan("hdl32e", cols=90)
    cols = xyz_columns(pts)
    cols["t"] = (np.arange(len(pts), dtype=np.uint32) * 1000 + 5_000).astype(np.uint32)  # ns
    cols["label"] = pack_label(np.full(len(pts), 10), np.full(len(pts), 3))
    scan = PcdSequence(write_pcd(tmp_path / "a.pcd", cols)).frame(0)
    assert scan.time[0] == 0.0 and scan.time[-1] == pytest.approx((len(pts) - 1) * 1e-6)
    assert set(scan.semantic) == {10} and set(scan.instance) == {3}


def test_pcd_folder_is_sequence(tmp_path: Path) -> None:
    for i in range(3):
        pts, _ = beam_scan("hdl32e", cols=90, seed=i)
        write_pcd(tmp_path / f"{i:04d}.pcd", xyz_columns(pts))
    seq = open_reader(tmp_path)
    assert seq.format == "pcd" and len(seq) == 3 and seq.frame_name(2) == "000002"
    assert seq.poses is None and any("no intensity" in w for w in seq.warnings)


def test_pcd_corrupt_file_names_it(tmp_path: Path) -> None:
    f = tmp_path / "bad.pcd"
    f.write_text("VERSION 0.7\nFIELDS x y\nnonsense\n")
    with pytest.raises(DataError, match="bad.pcd: cannot read PCD"):
        PcdSequence(f)


def test_pcd_without_xyz_names_it(tmp_path: Path) -> None:
    f = write_pcd(tmp_path / "a.pcd", {"a": np.zeros(3, np.float32), "b": np.zeros(3, np.float32)})
    with pytest.raises(DataError, match="a.pcd: needs x, y and z"):
        PcdSequence(f)


def test_ply_round_trip_with_float_intensity(tmp_path: Path) -> None:
    pts, rows = beam_scan("hdl32e", cols=90)
    cols = xyz_columns(pts)
    cols["scalar_intensity"] = np.full(len(pts), 0.25, np.float32)
    seq = open_reader(write_ply(tmp_path / "a.ply", cols))
    assert seq.format == "ply" and seq.sensor.name == "hdl32e"
    scan = seq.frame(0)
    np.testing.assert_array_equal(scan.points, pts)
    np.testing.assert_array_equal(scan.ring, rows)
    np.testing.assert_allclose(scan.intensity, 0.25)


def test_ply_nan_rows_dropped(tmp_path: Path) -> None:
    pts, _ = beam_scan("hdl32e", cols=90)
    pts[[0, 7]] = np.nan
    scan = PlySequence(write_ply(tmp_path / "a.ply", xyz_columns(pts))).frame(0)
    assert scan.dropped == 2 and len(scan) == len(pts) - 2


def test_ply_corrupt_file_names_it(tmp_path: Path) -> None:
    f = tmp_path / "bad.ply"
    f.write_bytes(
        b"ply\nformat binary_little_endian 1.0\nelement vertex 10\nproperty float x\nend_header\n\x00"
    )
    with pytest.raises(DataError, match="bad.ply"):
        PlySequence(f)


def test_pcd_folder_frames_in_natural_order(tmp_path: Path) -> None:
    for i in range(12):  # 0.pcd .. 11.pcd: a plain sort puts 10 and 11 before 2
        pts, _ = beam_scan("vlp16", cols=90, seed=i)
        write_pcd(tmp_path / f"{i}.pcd", xyz_columns(pts + np.float32(i)))
    seq = open_reader(tmp_path)
    assert [seq.frame_name(k) for k in range(12)] == [f"{i:06d}" for i in range(12)]
    assert seq.frame(10).points[0, 0] == pytest.approx(beam_scan("vlp16", cols=90, seed=10)[0][0, 0] + 10)


def test_pcd_unordered_cloud_beams_from_elevation_histogram(tmp_path: Path) -> None:
    pts, rows = beam_scan("vlp16", cols=1000)
    perm = np.random.default_rng(0).permutation(len(pts))
    seq = PcdSequence(write_pcd(tmp_path / "a.pcd", xyz_columns(pts[perm])))
    assert (seq.sensor.name, seq.sensor_from) == ("vlp16", "elevation histogram")
    np.testing.assert_array_equal(seq.frame(0).ring, rows[perm])


@pytest.mark.real_data
def test_pcd_real_nuscenes_keyframes_without_ring_are_32_beams(real_data: Path, tmp_path: Path) -> None:
    """nuScenes HDL-32E sweeps as x y z PCD keyframes in shuffled order: the histogram finds the
    32 beams (the HDL-32E preset), fitted by process to the sweep's 20 Hz width."""
    from pipeline.sequence import open_sequence

    raw = np.fromfile(next((real_data / "nuscenes_hdl32e").glob("*.pcd.bin")), np.float32).reshape(-1, 5)
    for i in range(2):
        perm = np.random.default_rng(i).permutation(len(raw))
        write_pcd(tmp_path / f"{i}.pcd", xyz_columns(np.ascontiguousarray(raw[perm, :3])))
    seq = open_sequence(tmp_path)
    assert (seq.sensor.name, seq.sensor.n_rings, seq.sensor_from) == ("hdl32e", 32, "elevation histogram")
    assert 1070 <= seq.sensor.width < 1100  # ~1,080 columns at 20 Hz


def test_pcd_folder_of_other_names_names_frames_by_place(tmp_path: Path) -> None:
    for name in ("scan_b", "scan_a"):
        pts, _ = beam_scan("vlp16", cols=90)
        write_pcd(tmp_path / f"{name}.pcd", xyz_columns(pts))
    assert [open_reader(tmp_path).frame_name(k) for k in range(2)] == ["000000", "000001"]


def test_pcd_folder_takes_its_poses_and_times(tmp_path: Path) -> None:
    for i in range(3):
        pts, _ = beam_scan("vlp16", cols=90, seed=i)
        write_pcd(tmp_path / f"{i}.pcd", xyz_columns(pts))
    poses = np.tile(np.eye(4), (3, 1, 1))
    poses[:, 0, 3] = [0.0, 0.5, 1.0]
    write_poses(tmp_path / "poses.txt", poses)
    (tmp_path / "times.txt").write_text("0.0\n0.1\n0.2\n")
    seq = open_reader(tmp_path)
    np.testing.assert_allclose(seq.poses[:, 0, 3], [0.0, 0.5, 1.0])  # no calib.txt: taken as T_world_lidar
    np.testing.assert_allclose(seq.times, [0.0, 0.1, 0.2])
    assert any("no calib.txt" in w for w in seq.warnings)
    (tmp_path / "poses.txt").write_text("1 0 0 0 0 1 0 0 0 0 1 0\n")
    with pytest.raises(DataError, match="poses.txt"):
        open_reader(tmp_path)  # one pose for three frames


@pytest.mark.real_data
def test_pcd_folder_of_real_scans_with_poses_is_processed_into_linked_tracks(real_data: Path, tmp_path: Path) -> None:
    # SemanticKITTI 00 frames 0-2 as 0.pcd, 1.pcd, 2.pcd beside the sequence's poses and calib:
    # outputs are NNNNNN.label, as for a KITTI folder, and the tracks are linked through the poses
    from pipeline.io.semantickitti import read_bin
    from pipeline.pipeline import run_process

    src, seq = real_data / "kitti_seq00", tmp_path / "pcd"
    seq.mkdir()
    for i in range(3):
        raw = read_bin(src / "velodyne" / f"{i:06d}.bin")
        cols = xyz_columns(np.ascontiguousarray(raw[:, :3]))
        cols["intensity"] = raw[:, 3]
        write_pcd(seq / f"{i}.pcd", cols)
    (seq / "poses.txt").write_text("\n".join((src / "poses.txt").read_text().splitlines()[:3]) + "\n")
    (seq / "calib.txt").write_text((src / "calib.txt").read_text())
    summary = run_process(seq, tmp_path / "out")
    assert summary["linked"] and summary["poses"] == "file" and summary["tracks_multi_frame"] > 100
    assert sorted(p.name for p in (tmp_path / "out" / "tracks").iterdir()) == [f"{i:06d}.label" for i in range(3)]
