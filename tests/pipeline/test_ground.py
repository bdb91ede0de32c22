"""Ground removal (pipeline.ground) on real scans."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from pipeline.io.semantickitti import read_bin


@pytest.mark.real_data
def test_predict_does_not_call_a_lone_point_above_the_road_ground(real_data: Path, tmp_path: Path) -> None:
    # one return 3 m above the road 12 m behind the car, written last (scan order puts it in
    # the bottom row, where the column walk used to take it as the first ground of its column)
    from pipeline.pipeline import PredictOptions, run_predict

    raw = read_bin(real_data / "kitti_seq00" / "velodyne" / "000000.bin")
    lone = np.float32([[-12.0, 2.0, 1.3, 0.3]])  # the road lies 1.7 m under the sensor
    (tmp_path / "seq" / "velodyne").mkdir(parents=True)
    np.concatenate([raw, lone]).tofile(tmp_path / "seq" / "velodyne" / "000000.bin")
    run_predict(tmp_path / "seq", None, tmp_path / "out", PredictOptions(device="cpu"))
    labels = np.fromfile(tmp_path / "out" / "labels" / "000000.label", np.uint32) & 0xFFFF
    assert len(labels) == len(raw) + 1
    assert labels[-1] != 40  # not road
    assert np.mean(labels[:-1] == 40) > 0.3  # the road still is
