from __future__ import annotations

import numpy as np
import pytest

from pipeline.io.beams import nearest_beam
from pipeline.io.layout import recover_rings
from pipeline.io.rings import check_rings, rows_from_ring_field, scan_order_rings
from pipeline.io.semantickitti import read_bin
from pipeline.sensors import get_sensor

KITTI_FRAMES = ["000003", "000010", "000011", "000012", "000013", "000014"]


def beam_scan(sensor_name: str = "hdl32e", cols: int = 720, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """(points (R*C, 3) float32 stored beam by beam from the top, counter-clockwise from +x; rows)."""
    sensor = get_sensor(sensor_name)
    rng = np.random.default_rng(seed)
    el = sensor.elevations_rad()[:, None]
    az = np.linspace(0.0, 2 * np.pi, cols, endpoint=False)[None, :] + 1e-3
    r = rng.uniform(5.0, 40.0, size=(sensor.n_rings, cols))
    pts = np.stack([r * np.cos(el) * np.cos(az), r * np.cos(el) * np.sin(az), r * np.sin(el) + 0 * az], -1)
    rows = np.repeat(np.arange(sensor.n_rings), cols)
    return pts.reshape(-1, 3).astype(np.float32), rows


def test_scan_order_rings_beam_by_beam_top_first() -> None:
    pts, rows = beam_scan()
    got, found = scan_order_rings(pts, 32)
    assert found == 32
    np.testing.assert_array_equal(got, rows)


def test_scan_order_rings_bottom_first_is_flipped() -> None:
    pts, rows = beam_scan()
    r = 32
    order = np.concatenate([np.flatnonzero(rows == k) for k in range(r - 1, -1, -1)])
    got, _ = scan_order_rings(pts[order], r)
    np.testing.assert_array_equal(got, rows[order])


def test_scan_order_rings_clockwise_storage() -> None:
    pts, rows = beam_scan()
    mirrored = pts * np.array([1, -1, 1], dtype=np.float32)  # same rows, azimuth runs clockwise
    got, _ = scan_order_rings(mirrored, 32)
    np.testing.assert_array_equal(got, rows)


def test_scan_order_rings_jitter_across_the_cut_is_merged() -> None:
    pts, rows = beam_scan(cols=720)
    # the 2nd point of ring 5 jitters to just below azimuth 0: a one-point wrap inside the ring
    i = 5 * 720 + 1
    r = np.hypot(pts[i, 0], pts[i, 1])
    pts[i, 0], pts[i, 1] = r * np.cos(-1e-4), r * np.sin(-1e-4)
    got, found = scan_order_rings(pts, 32)
    assert found == 32
    np.testing.assert_array_equal(got, rows)


def test_recover_rings_shuffled_falls_back_to_elevation() -> None:
    pts, rows = beam_scan()
    perm = np.random.default_rng(1).permutation(len(pts))
    rec = recover_rings(pts[perm], get_sensor("hdl32e"))
    assert rec.method == "elevation"
    assert rec.ring.dtype == np.int16
    np.testing.assert_array_equal(rec.ring, rows[perm])


def test_recover_rings_wrong_beam_count_falls_back() -> None:
    pts, _ = beam_scan("vlp16")
    rec = recover_rings(pts, get_sensor("hdl32e"))
    assert rec.method == "elevation" and rec.found == 16


def test_rows_from_ring_field_flips_bottom_first_numbering() -> None:
    pts, rows = beam_scan()
    np.testing.assert_array_equal(rows_from_ring_field(pts, 31 - rows, 32), rows)
    np.testing.assert_array_equal(rows_from_ring_field(pts, rows, 32), rows)


def test_check_rings_exact_rows_have_no_wrong_points() -> None:
    pts, rows = beam_scan()
    check = check_rings(pts, rows, 32)
    assert check.rows == 32 and check.monotonic
    assert check.wrong_fraction == 0.0


def test_check_rings_detects_moved_points() -> None:
    pts, rows = beam_scan()
    moved = rows.copy()
    pick = np.random.default_rng(2).random(len(rows)) < 0.05
    moved[pick] = np.clip(moved[pick] + 1, 0, 31)
    check = check_rings(pts, moved, 32)
    truly = (moved != rows).mean()
    assert check.wrong_fraction > 0.9 * truly


@pytest.mark.parametrize("name", KITTI_FRAMES)
def test_recover_rings_kitti_rows_are_lasers(real_data, name: str) -> None:
    """Scan-order rows on real HDL-64E frames: 64 rows, falling elevation, < 1% in a wrong ring."""
    pts = read_bin(real_data / "kitti_seq09" / "velodyne" / f"{name}.bin")[:, :3]
    rec = recover_rings(pts, get_sensor("hdl64e"))
    assert rec.method == "scan_order" and rec.found == 64
    check = check_rings(pts, rec.ring, 64)
    assert check.rows == 64 and check.monotonic
    assert check.wrong_fraction < 0.01, check.wrong_fraction


def test_check_rings_kitti_flags_elevation_rows(real_data) -> None:
    """The check separates: nearest-elevation rows (laser origin offsets ignored) fail it on KITTI."""
    pts = read_bin(real_data / "kitti_seq09" / "velodyne" / "000010.bin")[:, :3].astype(np.float64)
    el = np.degrees(np.arctan2(pts[:, 2], np.hypot(pts[:, 0], pts[:, 1])))
    rows = nearest_beam(el, np.asarray(get_sensor("hdl64e").elevations_deg))
    assert check_rings(pts, rows, 64).wrong_fraction > 0.02
