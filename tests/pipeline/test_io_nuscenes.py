from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from pipeline.errors import DataError
from pipeline.io import open_reader
from pipeline.io.nuscenes import NuScenesSequence

NAME = "n015-2018-07-24-11-22-45+0800__LIDAR_TOP__{stamp}.pcd.bin"


def write_sweep(path: Path, rows: np.ndarray) -> Path:
    np.asarray(rows, dtype=np.float32).tofile(path)
    return path


def test_nuscenes_axes_ring_and_intensity_converted(tmp_path: Path) -> None:
    # nuScenes frame: x right, y forward. A point 5 m ahead on ring 31 (top), one 2 m to the right on ring 0.
    f = write_sweep(tmp_path / "a.pcd.bin", [[0.0, 5.0, 0.5, 255.0, 31.0], [2.0, 0.0, -1.0, 51.0, 0.0]])
    scan = NuScenesSequence(f).frame(0)
    np.testing.assert_allclose(scan.points, [[5.0, 0.0, 0.5], [0.0, -2.0, -1.0]])
    np.testing.assert_array_equal(scan.ring, [0, 31])
    np.testing.assert_allclose(scan.intensity, [1.0, 0.2])


def test_nuscenes_folder_is_sequence_with_times(tmp_path: Path) -> None:
    for stamp in (1532402927647951, 1532402927697951):
        write_sweep(tmp_path / NAME.format(stamp=stamp), np.zeros((4, 5)) + 1)
    seq = open_reader(tmp_path)
    assert seq.format == "nuscenes" and len(seq) == 2 and seq.poses is None
    np.testing.assert_allclose(np.diff(seq.times), [0.05], atol=1e-6)
    assert seq.frame_name(0).endswith("1532402927647951")


def test_nuscenes_bad_size_names_file(tmp_path: Path) -> None:
    f = tmp_path / "x.pcd.bin"
    np.zeros(7, np.float32).tofile(f)
    with pytest.raises(DataError, match="x.pcd.bin: size 28 bytes"):
        NuScenesSequence(f).frame(0)


def test_nuscenes_ring_out_of_range_names_file(tmp_path: Path) -> None:
    f = write_sweep(tmp_path / "x.pcd.bin", [[1.0, 1.0, 0.0, 3.0, 40.0]])
    with pytest.raises(DataError, match="x.pcd.bin: ring field"):
        NuScenesSequence(f).frame(0)


def test_nuscenes_nan_rows_dropped(tmp_path: Path) -> None:
    f = write_sweep(tmp_path / "x.pcd.bin", [[1.0, 1.0, 0.0, 3.0, 4.0], [np.nan, 1.0, 0.0, 3.0, 4.0]])
    scan = NuScenesSequence(f).frame(0)
    assert len(scan) == 1 and scan.dropped == 1


def test_nuscenes_real_sweep_row0_is_top(real_data: Path) -> None:
    f = next((real_data / "nuscenes_hdl32e").glob("*.pcd.bin"))
    seq = open_reader(f)
    scan = seq.frame(0)
    assert len(scan) == 34_688 and seq.sensor.n_rings == 32
    assert 0.0 <= scan.intensity.min() and scan.intensity.max() <= 1.0
    p = scan.points.astype(np.float64)
    el = np.degrees(np.arctan2(p[:, 2], np.hypot(p[:, 0], p[:, 1])))
    med = np.array([np.median(el[scan.ring == r]) for r in range(32)])
    assert np.all(np.diff(med) < 0)  # row 0 is the top beam
    assert med[0] == pytest.approx(10.6, abs=0.2) and med[31] == pytest.approx(-30.6, abs=0.2)


@pytest.mark.real_data
def test_nuscenes_ego_vehicle_returns_never_become_tracks(real_data: Path, tmp_path: Path) -> None:
    # the car's roof and the sensor mount return thousands of points within 3 m of the axis
    from pipeline.config import PipelineConfig
    from pipeline.pipeline import run_process

    sweep = next((real_data / "nuscenes_hdl32e").glob("*.pcd.bin"))
    raw = np.fromfile(sweep, np.float32).reshape(-1, 5)
    car = np.hypot(raw[:, 0], raw[:, 1]) < 3.0  # nothing but the car lies this near in this sweep
    labels = {}
    for name, box in (("default", None), ("no box", ())):
        config = PipelineConfig().override({"range_image": {"ego_box": box}})
        run_process(sweep, tmp_path / name, config)
        labels[name] = np.fromfile(tmp_path / name / "tracks" / f"{sweep.name[:-8]}.label", np.uint32)
        assert len(labels[name]) == len(raw)
    assert not labels["default"][car].any()
    assert len(np.unique(labels["no box"][car])) > 10  # without the car's box its returns made tracks
