"""Bad points never break the contract: one value per input point, whatever the input holds
(NaN, inf, all-zero rows, points beyond max_range, 1e9 m, float32's largest values, no points)."""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from pipeline.config import PipelineConfig
from pipeline.ground import estimate_ground
from pipeline.io.semantickitti import write_calib_identity, write_poses
from pipeline.processing import SequenceProcessor
from pipeline.range_image import project
from pipeline.scan import Scan
from pipeline.sensors import get_sensor
from pipeline.sequence import open_sequence
from tests.pipeline.test_rings import beam_scan

BIG = float(np.finfo(np.float32).max)
# the bad rows a scan file can hold: x y z remission
BAD_ROWS = {
    "nan": (np.nan, 1.0, 0.0, 0.5),
    "inf": (np.inf, 0.0, 1.0, 0.5),
    "-inf": (2.0, -np.inf, 0.0, 0.5),
    "nan_remission": (5.0, 1.0, -1.0, np.nan),
    "zero": (0.0, 0.0, 0.0, 0.0),
    "beyond_max_range": (400.0, 30.0, 2.0, 0.5),
    "1e9": (1e9, -1e9, 1e9, 0.5),
    "float32_max": (BIG, BIG, -BIG, 0.5),
}


@st.composite
def bad_scans(draw) -> np.ndarray:
    """(N, 4) float32 rows of a scan file: a 32-beam scan (or none) with bad rows inserted."""
    if draw(st.booleans()):
        pts, _ = beam_scan("hdl32e", cols=90, seed=draw(st.integers(0, 3)))
        rows = np.column_stack([pts, np.full(len(pts), 0.5, np.float32)])
    else:
        rows = np.zeros((0, 4), np.float32)
    kinds = draw(st.lists(st.sampled_from(sorted(BAD_ROWS)), max_size=40))
    for kind in kinds:
        at = draw(st.integers(0, len(rows)))
        rows = np.insert(rows, at, np.asarray(BAD_ROWS[kind], np.float32), axis=0)
    return rows.astype(np.float32)


def write_kitti(root: Path, frames: list[np.ndarray]) -> Path:
    """A KITTI folder of the given raw frames, with poses (so that association runs too)."""
    (root / "velodyne").mkdir(parents=True)
    for i, raw in enumerate(frames):
        raw.astype(np.float32).tofile(root / "velodyne" / f"{i:06d}.bin")
    poses = np.tile(np.eye(4), (len(frames), 1, 1))
    poses[:, 0, 3] = 0.3 * np.arange(len(frames))
    write_poses(root / "poses.txt", poses)
    write_calib_identity(root / "calib.txt")
    return root


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(first=bad_scans(), second=bad_scans(), sensor=st.sampled_from(["hdl32e", "auto"]))
def test_pipeline_bad_scans_one_label_per_input_point(first: np.ndarray, second: np.ndarray, sensor: str) -> None:
    """Reader, projection, ground, segmentation, samples and association over two bad frames."""
    with tempfile.TemporaryDirectory() as tmp:
        seq = open_sequence(write_kitti(Path(tmp) / "seq", [first, second]), sensor=sensor)
        proc = SequenceProcessor(PipelineConfig(), seq.sensor)
        frames = list(proc.iter_frames(seq.source, poses=seq.poses))
    assert [len(fr.scan.to_input(fr.track_labels())) for fr in frames] == [len(first), len(second)]
    for fr, raw in zip(frames, (first, second), strict=True):
        labels = fr.scan.to_input(fr.track_labels())
        bad = ~np.isfinite(raw).all(axis=1)
        assert not labels[bad].any()  # a NaN or inf row is no point of any track
        assert np.isfinite(fr.height).all()


def test_scan_to_input_spreads_values_to_kept_rows() -> None:
    rows = np.array([True, False, True, True, False])
    scan = Scan(np.zeros((3, 3), np.float32), np.zeros(3, np.float32), np.zeros(3, np.int16), input_rows=rows)
    np.testing.assert_array_equal(scan.to_input(np.array([7, 8, 9]), fill=-1), [7, -1, 8, 9, -1])
    assert scan.n_input == 5


def test_scan_select_keeps_the_input_rows_of_kept_points() -> None:
    rows = np.array([True, False, True, True])
    scan = Scan(np.zeros((3, 3), np.float32), np.zeros(3, np.float32), np.zeros(3, np.int16), input_rows=rows)
    picked = scan.select(np.array([False, True, True]))
    np.testing.assert_array_equal(picked.input_rows, [False, False, True, True])


def test_ground_grid_ignores_points_far_beyond_max_range() -> None:
    """100 points at 1e9 m (MemoryError before) and one at float32's largest value: the surface
    grid spans the ground points only; every height is finite."""
    sensor = get_sensor("hdl32e")
    pts, rows = beam_scan("hdl32e", cols=360)
    pts[:, 2] = np.minimum(pts[:, 2], -1.7)  # the lower beams see flat ground
    far = np.tile(np.float32([1e9, 1e9, 5.0]), (100, 1))
    far[-1] = [BIG, -BIG, BIG]
    scan = Scan(np.vstack([pts, far]), np.zeros(len(pts) + 100, np.float32),
                np.concatenate([rows, np.zeros(100, int)]).astype(np.int16))
    image = project(scan, sensor)
    g = estimate_ground(scan, image)
    assert np.isfinite(g.height).all() and not g.ground[-100:].any()
