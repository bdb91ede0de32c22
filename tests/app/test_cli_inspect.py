"""`tracklabel inspect`: the summary, and a one-line error with exit code 2 for bad input."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from app.cli import app
from pipeline.io.semantickitti import read_bin, write_label, write_poses
from tests.pipeline.test_io_kitti import pose, write_sequence
from tests.pipeline.test_io_pointfiles import write_pcd, xyz_columns
from tests.pipeline.test_organized import kitti_organized, write_organized_bin

runner = CliRunner()


def inspect(path: Path):
    return runner.invoke(app, ["inspect", str(path)])


def assert_one_line_error(result, name: str) -> None:
    assert result.exit_code == 2, (result.exit_code, result.stdout, result.stderr)
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ") and name in lines[0], lines
    assert "Traceback" not in result.stdout + result.stderr


def test_cli_inspect_prints_summary(tmp_path: Path) -> None:
    result = inspect(write_sequence(tmp_path / "seq", frames=2, cols=100))
    assert result.exit_code == 0, result.stderr
    for text in ("format:  kitti", "sensor:  hdl32e (32 beams x 2160 columns), from metadata", "frames:  2",
                 "poses:   given", "ground"):
        assert text in result.stdout


def test_cli_inspect_counts_labels_in_the_label_set_given(tmp_path: Path) -> None:
    seq = write_sequence(tmp_path / "seq", frames=1, cols=100)  # SemanticKITTI ids 40 (road) and 10 (car)
    result = runner.invoke(app, ["inspect", str(seq), "--label-set", "semantickitti"])
    assert result.exit_code == 0, result.stderr
    names = [line.split()[0] for line in result.stdout.split("classes:")[1].strip().splitlines()]
    assert "road" in names and "sidewalk" in names and "ground" not in names
    assert_one_line_error(runner.invoke(app, ["inspect", str(seq), "--label-set", "nope"]), "nope")


def test_cli_inspect_warns_about_dropped_rows(tmp_path: Path) -> None:
    root = write_sequence(tmp_path / "seq", frames=1, cols=100, labels=False, poses=False)
    f = root / "velodyne" / "000000.bin"
    raw = read_bin(f).copy()
    raw[3, 1] = np.inf
    raw.tofile(f)
    result = inspect(root)
    assert result.exit_code == 0
    assert "warning: 1 rows with NaN or inf were dropped" in result.stderr


def test_cli_inspect_truncated_bin(tmp_path: Path) -> None:
    root = write_sequence(tmp_path / "seq", frames=2, cols=100, labels=False)
    f = root / "velodyne" / "000001.bin"
    f.write_bytes(f.read_bytes()[:-4])
    assert_one_line_error(inspect(root), "000001.bin")


def test_cli_inspect_label_count_mismatch(tmp_path: Path) -> None:
    root = write_sequence(tmp_path / "seq", frames=2, cols=100)
    write_label(root / "labels" / "000001.label", np.zeros(5, np.uint16), np.zeros(5, np.uint16))
    assert_one_line_error(inspect(root), "000001.label")


def test_cli_inspect_poses_line_count(tmp_path: Path) -> None:
    root = write_sequence(tmp_path / "seq", frames=3, cols=100)
    write_poses(root / "poses.txt", np.stack([pose(0.0)] * 4))
    assert_one_line_error(inspect(root), "poses.txt")


def test_cli_inspect_empty_folder(tmp_path: Path) -> None:
    (tmp_path / "empty").mkdir()
    assert_one_line_error(inspect(tmp_path / "empty"), "empty")


def test_cli_inspect_unknown_folder(tmp_path: Path) -> None:
    (tmp_path / "odd").mkdir()
    (tmp_path / "odd" / "readme.txt").write_text("not lidar")
    assert_one_line_error(inspect(tmp_path / "odd"), "odd")


def test_cli_inspect_missing_path(tmp_path: Path) -> None:
    assert_one_line_error(inspect(tmp_path / "nope"), "nope")


@pytest.mark.real_data
def test_cli_inspect_real_kitti_shuffled_names_64_beams(real_data: Path, tmp_path: Path) -> None:
    (tmp_path / "velodyne").mkdir()
    for name in ("000000", "000001"):
        raw = read_bin(real_data / "kitti_seq00" / "velodyne" / f"{name}.bin")
        raw[np.random.default_rng(0).permutation(len(raw))].tofile(tmp_path / "velodyne" / f"{name}.bin")
    result = inspect(tmp_path)
    assert result.exit_code == 0, result.stderr
    assert "sensor:  hdl64e (64 beams x 2048 columns), from elevation histogram" in result.stdout


@pytest.mark.real_data
def test_cli_inspect_real_organized_64x2048(real_data: Path, tmp_path: Path) -> None:
    grid = kitti_organized(real_data)
    result = inspect(write_organized_bin(tmp_path / "velodyne" / "000000.bin", grid).parent.parent)
    assert result.exit_code == 0, result.stderr
    assert "sensor:  hdl64e (64 beams x 2048 columns), from organized layout" in result.stdout


@pytest.mark.real_data
def test_cli_inspect_real_nuscenes_pcd_without_ring_names_32_beams(real_data: Path, tmp_path: Path) -> None:
    raw = np.fromfile(next((real_data / "nuscenes_hdl32e").glob("*.pcd.bin")), np.float32).reshape(-1, 5)
    for i in range(3):
        xyz = np.ascontiguousarray(raw[np.random.default_rng(i).permutation(len(raw)), :3])
        write_pcd(tmp_path / f"{i}.pcd", xyz_columns(xyz))
    result = inspect(tmp_path)
    assert result.exit_code == 0, result.stderr
    assert "sensor:  hdl32e (32 beams x " in result.stdout and "from elevation histogram" in result.stdout


@pytest.mark.real_data
def test_cli_inspect_real_ouster_bin_stored_column_by_column_is_organized(real_data: Path, tmp_path: Path) -> None:
    from tests.pipeline.test_organized import column_by_column, ouster_grid

    grid, _ = ouster_grid(real_data)
    result = inspect(write_organized_bin(tmp_path / "velodyne" / "000000.bin",
                                         column_by_column(grid, 128, 1024)).parent.parent)
    assert result.exit_code == 0, result.stderr
    assert "(128 beams x 1024 columns), from organized layout" in result.stdout


@pytest.mark.real_data
def test_cli_inspect_real_scan_written_twice_is_64_beams(real_data: Path, tmp_path: Path) -> None:
    (tmp_path / "velodyne").mkdir()
    raw = read_bin(real_data / "kitti_seq00" / "velodyne" / "000000.bin")
    np.concatenate([raw, raw]).tofile(tmp_path / "velodyne" / "000000.bin")
    result = inspect(tmp_path)
    assert result.exit_code == 0, result.stderr
    assert "sensor:  hdl64e (64 beams x 2048 columns), from scan order" in result.stdout


@pytest.mark.real_data
def test_cli_inspect_real_camera_view_crop_keeps_the_columns_of_a_revolution(real_data: Path, tmp_path: Path) -> None:
    # KITTI's camera-view crop: the front 90 degrees of an HDL-64E scan, 2048 columns a turn
    (tmp_path / "velodyne").mkdir()
    raw = read_bin(real_data / "kitti_seq00" / "velodyne" / "000000.bin")
    front = (raw[:, 0] > 0) & (np.abs(raw[:, 1]) < raw[:, 0])
    raw[front].tofile(tmp_path / "velodyne" / "000000.bin")
    result = inspect(tmp_path)
    assert result.exit_code == 0, result.stderr
    assert "sensor:  hdl64e (64 beams x 2048 columns), from scan order" in result.stdout
    named = runner.invoke(app, ["inspect", str(tmp_path), "--sensor", "hdl64e"])
    assert "(64 beams x 2048 columns), from user flag" in named.stdout, named.stdout
