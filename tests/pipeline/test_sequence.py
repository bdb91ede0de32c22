"""pipeline.sequence.open_sequence: reader, sensor (and how it was decided), width, poses."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from pipeline.errors import DataError
from pipeline.io.semantickitti import write_bin
from pipeline.scan import Scan
from pipeline.sensors import get_sensor
from pipeline.sequence import fit_width, open_sequence
from tests.pipeline.test_io_kitti import write_sequence
from tests.pipeline.test_organized import organize, write_organized_bin
from tests.pipeline.test_rings import beam_scan


def ring_scan(per_ring: int, n_rings: int = 32, turn: float = 1.0) -> Scan:
    """`per_ring` points on each of `n_rings` rings, 10 m away, spread evenly over `turn` of a
    revolution."""
    ring = np.repeat(np.arange(n_rings), per_ring).astype(np.int16)
    az = np.tile(np.arange(per_ring) * (2.0 * np.pi * turn / per_ring), n_rings)
    pts = np.stack([10.0 * np.cos(az), 10.0 * np.sin(az), np.zeros_like(az)], axis=1).astype(np.float32)
    return Scan(pts, np.zeros(len(ring), np.float32), ring)


def test_fit_width_narrows_a_faster_spinning_sensor() -> None:
    fitted = fit_width(ring_scan(1084), get_sensor("hdl32e"))  # nuScenes: 20 Hz
    assert fitted.width == 1090 and fitted.frequency_hz == pytest.approx(10.0 * 2160 / 1090)


def test_fit_width_keeps_a_full_sensor() -> None:
    assert fit_width(ring_scan(2100), get_sensor("hdl32e")).width == 2160


def test_fit_width_counts_the_columns_of_a_whole_revolution_in_a_partial_scan() -> None:
    # a quarter of a turn (a camera-view crop) holding 512 points per ring is a 2048-column
    # sensor, not a 515-column one, named or not
    assert fit_width(ring_scan(512, 64, turn=0.25), get_sensor("hdl64e")).width == 2048
    measured = dataclasses.replace(get_sensor("hdl64e"), name="kitti-64beam", width=2048)
    assert fit_width(ring_scan(512, 64, turn=0.25), measured).width == 2048


def test_fit_width_ignores_points_at_the_sensor() -> None:
    scan = ring_scan(1084)
    pts = np.vstack([scan.points, np.zeros((5000, 3), np.float32)])  # nuScenes' no-return placeholders
    ring = np.concatenate([scan.ring, np.full(5000, 20, np.int16)])
    fitted = fit_width(Scan(pts, np.zeros(len(pts), np.float32), ring), get_sensor("hdl32e"))
    assert fitted.width == 1090


def test_open_sequence_metadata_sensor_and_file_poses(tmp_path: Path) -> None:
    seq = open_sequence(write_sequence(tmp_path / "seq", frames=2, cols=100))
    assert (seq.sensor.name, seq.sensor_from, seq.pose_source) == ("hdl32e", "metadata", "file")
    assert seq.poses is not None and seq.poses.shape == (2, 4, 4) and len(seq) == 2


def test_open_sequence_user_flag_sets_the_readers_rows(tmp_path: Path) -> None:
    """A 16-beam scan read as an HDL-32E: the flag wins, and rows follow its 32 beams."""
    root = write_sequence(tmp_path / "seq", frames=1, sensor=None, poses=False, labels=False, cols=100)
    pts, _ = beam_scan("vlp16", cols=400)
    write_bin(root / "velodyne" / "000000.bin", pts, np.zeros(len(pts), np.float32))
    assert open_sequence(root).sensor.name == "vlp16"
    seq = open_sequence(root, sensor="hdl32e")
    assert (seq.sensor.name, seq.sensor_from, seq.pose_source) == ("hdl32e", "user flag", "none")
    rows = seq.source.frame(0).ring
    assert rows.max() < 32 and len(np.unique(rows)) == 16


def test_open_sequence_organized_layout_keeps_its_width(tmp_path: Path) -> None:
    """Half the pixels without return: a fitted width would halve the image; W is stated."""
    pts, rows = beam_scan("hdl32e", cols=720)
    grid = organize(pts, rows, 32, 720)
    grid[np.random.default_rng(0).random(len(grid)) < 0.5] = 0.0
    seq = open_sequence(write_organized_bin(tmp_path / "velodyne" / "000000.bin", grid))
    assert (seq.sensor.name, seq.sensor.width, seq.sensor_from) == ("hdl32e", 720, "organized layout")


def test_open_sequence_bad_poses_value(tmp_path: Path) -> None:
    with pytest.raises(DataError, match="'gps'"):
        open_sequence(write_sequence(tmp_path / "seq", frames=1), poses="gps")


def test_open_sequence_no_frames_names_the_folder(tmp_path: Path) -> None:
    (tmp_path / "velodyne").mkdir()
    with pytest.raises(DataError, match="velodyne"):
        open_sequence(tmp_path)


@pytest.mark.real_data
@pytest.mark.parametrize("sensor", ["auto", "hdl64e"])
def test_open_sequence_real_camera_view_crop_keeps_every_points_pixel(real_data: Path, tmp_path: Path, sensor: str) -> None:
    # KITTI's camera-view crop (the front 90 degrees): fitted as 452 columns for a whole turn,
    # three quarters of its points shared a pixel with another and lost their own
    from pipeline.io.semantickitti import read_bin
    from pipeline.range_image import project

    raw = read_bin(real_data / "kitti_seq00" / "velodyne" / "000000.bin")
    front = (raw[:, 0] > 0) & (np.abs(raw[:, 1]) < raw[:, 0])
    (tmp_path / "velodyne").mkdir()
    raw[front].tofile(tmp_path / "velodyne" / "000000.bin")
    seq = open_sequence(tmp_path, sensor=sensor)
    assert seq.sensor.width == 2048
    scan = seq.source.frame(0)
    assert project(scan, seq.sensor).owner_mask().mean() > 0.9
