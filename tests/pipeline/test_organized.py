"""Organized H x W scans (zeros where no return) recognised by their geometry (pipeline.io.organized)
and read by the KITTI reader as such."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from pipeline.io.kitti import KittiSequence
from pipeline.io.organized import organized_shape
from pipeline.io.rings import scan_order_rings
from pipeline.io.semantickitti import read_bin
from pipeline.range_image import azimuth_columns
from tests.pipeline.test_rings import beam_scan


def organize(points: np.ndarray, rows: np.ndarray, height: int, width: int) -> np.ndarray:
    """(H * W, 3) float32 of an organized scan: each point at its row and azimuth column (the
    nearest one where two meet), zeros where no point fell."""
    grid = np.zeros((height, width, 3), np.float32)
    order = np.argsort(-np.linalg.norm(points, axis=1))  # the nearest is written last
    grid[rows[order], azimuth_columns(points, width)[order]] = points[order]
    return grid.reshape(-1, 3)


def kitti_organized(real_data: Path) -> np.ndarray:
    """A real HDL-64E scan (KITTI seq 00 frame 0) as an organized 64 x 2048 layout, like an
    OS1-64 scan saved as a KITTI .bin (87 % of the pixels hold a return)."""
    pts = read_bin(real_data / "kitti_seq00" / "velodyne" / "000000.bin")[:, :3]
    rows, found = scan_order_rings(pts, 64)
    assert rows is not None and found == 64
    return organize(pts, rows, 64, 2048)


def write_organized_bin(path: Path, xyz: np.ndarray) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    np.column_stack([xyz, np.where((xyz != 0).any(axis=1), 0.3, 0.0)]).astype(np.float32).tofile(path)
    return path


def test_organized_shape_synthetic_scan_with_missing_returns() -> None:
    pts, rows = beam_scan("hdl32e", cols=720)
    grid = organize(pts, rows, 32, 720)
    grid[np.random.default_rng(0).random(len(grid)) < 0.3] = 0.0  # 30 % no return
    assert organized_shape(grid) == (32, 720, True, False)
    assert organized_shape(grid.reshape(32, 720, 3)[::-1].reshape(-1, 3)) == (32, 720, False, False)


def test_organized_shape_unordered_cloud_is_none() -> None:
    pts, _ = beam_scan("hdl32e", cols=720)
    assert organized_shape(pts[np.random.default_rng(0).permutation(len(pts))]) is None


def test_organized_shape_scan_order_of_unequal_rings_is_none() -> None:
    pts, rows = beam_scan("hdl32e", cols=720)
    keep = np.random.default_rng(1).random(len(pts)) < 0.9  # rings of different lengths
    assert organized_shape(pts[keep][: 32 * 640]) is None


@pytest.mark.real_data
def test_organized_shape_real_kitti_64x2048(real_data: Path) -> None:
    grid = kitti_organized(real_data)
    assert organized_shape(grid) == (64, 2048, True, False)
    cut = np.random.default_rng(0).choice(len(grid), 2048, replace=False)
    removed = np.delete(grid, cut, axis=0)  # 2048 pixels cut out (not zeroed): the rows slip
    assert len(removed) == 63 * 2048 and organized_shape(removed) is None


@pytest.mark.real_data
def test_organized_shape_real_ouster_128x1024(real_data: Path) -> None:
    pytest.importorskip("ouster.sdk")
    from pipeline.io import open_reader

    scan = open_reader(real_data / "ouster" / "OS-1-128_v2.3.0_1024x10_lb_n3.pcap").frame(0)
    assert organized_shape(organize(scan.points, scan.ring, 128, 1024)) == (128, 1024, True, False)


@pytest.mark.real_data
def test_kitti_reader_organized_bin_rows_columns_and_no_return(real_data: Path, tmp_path: Path) -> None:
    grid = kitti_organized(real_data)
    seq = KittiSequence(write_organized_bin(tmp_path / "velodyne" / "000000.bin", grid))
    assert (seq.sensor_from, seq.sensor.n_rings, seq.sensor.width) == ("organized layout", 64, 2048)
    scan = seq.frame(0)
    hit = (grid != 0).any(axis=1)
    assert len(scan) == hit.sum() and scan.n_input == 64 * 2048 and scan.dropped == 0
    np.testing.assert_array_equal(scan.ring, np.repeat(np.arange(64), 2048)[hit])
    np.testing.assert_array_equal(scan.to_input(np.ones(len(scan), np.uint8)), hit)


def ouster_grid(real_data: Path) -> tuple[np.ndarray, np.ndarray]:
    """A real Ouster OS-1-128 scan as its sensor stores it: ((128 * 1024, 3) float32 row by row,
    zeros for no return; (128 * 1024,) int16 ring of each pixel, -1 for no return)."""
    pytest.importorskip("ouster.sdk")
    from pipeline.io import open_reader

    scan = open_reader(real_data / "ouster" / "OS-1-128_v2.3.0_1024x10_lb_n3.pcap").frame(0)
    return scan.to_input(scan.points), scan.to_input(scan.ring, fill=-1)


def column_by_column(values: np.ndarray, height: int, width: int) -> np.ndarray:
    """Per-pixel values stored row by row re-stored column by column."""
    return np.ascontiguousarray(np.swapaxes(values.reshape(height, width, *values.shape[1:]), 0, 1)).reshape(values.shape)


@pytest.mark.real_data
def test_organized_shape_real_ouster_stored_column_by_column(real_data: Path, tmp_path: Path) -> None:
    grid, ring = ouster_grid(real_data)
    stored = column_by_column(grid, 128, 1024)
    assert organized_shape(stored) == (128, 1024, True, True)
    # read as a KITTI .bin: organized, its zeros are no points, every point in its beam's row
    seq = KittiSequence(write_organized_bin(tmp_path / "velodyne" / "000000.bin", stored))
    assert (seq.sensor_from, seq.sensor.n_rings, seq.sensor.width) == ("organized layout", 128, 1024)
    scan = seq.frame(0)
    hit = (stored != 0).any(axis=1)
    assert len(scan) == hit.sum() and not (scan.points == 0).all(axis=1).any()
    np.testing.assert_array_equal(scan.ring, column_by_column(ring, 128, 1024)[hit])


@pytest.mark.real_data
def test_kitti_reader_organized_bin_stored_column_by_column(real_data: Path, tmp_path: Path) -> None:
    stored = column_by_column(kitti_organized(real_data), 64, 2048)
    seq = KittiSequence(write_organized_bin(tmp_path / "velodyne" / "000000.bin", stored))
    assert (seq.sensor_from, seq.sensor.n_rings, seq.sensor.width) == ("organized layout", 64, 2048)
    hit = (stored != 0).any(axis=1)
    np.testing.assert_array_equal(seq.frame(0).ring, np.tile(np.arange(64), 2048)[hit])
