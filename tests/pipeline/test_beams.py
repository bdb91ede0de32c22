"""Beams of unordered clouds from their elevations (pipeline.io.beams), on synthetic clouds,
the simulator and real recordings (KITTI HDL-64E, nuScenes HDL-32E, Ouster) without ring and
scan order."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from pipeline.io.beams import beam_rows, find_beams, nearest_beam
from pipeline.io.rings import scan_order_rings
from pipeline.io.semantickitti import read_bin
from pipeline.sensors import get_sensor


def laser_cloud(
    sensor_name: str, cols: int = 1000, heights: np.ndarray | float = 0.0, seed: int = 0
) -> tuple[np.ndarray, np.ndarray]:
    """(points (R*C, 3) float32 shuffled, rows (R*C,)) of a sensor 1.7 m above the road of a street
    between two walls 8 m to the left and right (ranges from 2 to 40 m), its lasers `heights` (R,)
    metres above the origin, with 1 cm range noise."""
    sensor = get_sensor(sensor_name)
    rng = np.random.default_rng(seed)
    el = sensor.elevations_rad()[:, None]
    az = np.linspace(-np.pi, np.pi, cols, endpoint=False)[None, :] + rng.uniform(0, 2 * np.pi / cols, (sensor.n_rings, 1))
    h = np.broadcast_to(np.asarray(heights, np.float64), (sensor.n_rings,))[:, None]
    wall = 8.0 / np.maximum(np.abs(np.sin(az)), 1e-3)
    road = np.where(el < 0, (1.7 + h) / np.tan(np.maximum(-el, 1e-6)), np.inf)
    rho = np.minimum(np.minimum(wall, road), 40.0) + rng.normal(0, 0.01, (sensor.n_rings, cols))
    pts = np.stack([rho * np.cos(az), rho * np.sin(az), h + rho * np.tan(el)], -1)
    rows = np.repeat(np.arange(sensor.n_rings), cols)
    perm = rng.permutation(rows.size)
    return pts.reshape(-1, 3)[perm].astype(np.float32), rows[perm]


def shuffled(points: np.ndarray, *others: np.ndarray, seed: int = 0) -> tuple[np.ndarray, ...]:
    perm = np.random.default_rng(seed).permutation(len(points))
    return (points[perm], *(o[perm] for o in others))


@settings(max_examples=50, deadline=None)
@given(beam=st.integers(0, 63), frac=st.floats(-0.45, 0.45))
def test_nearest_beam_within_half_a_gap(beam: int, frac: float) -> None:
    el = np.asarray(get_sensor("hdl64e").elevations_deg)
    # the beams are not evenly spaced: stay within half the nearer neighbour's gap
    gaps = ([el[beam - 1] - el[beam]] if beam > 0 else []) + ([el[beam] - el[beam + 1]] if beam < 63 else [])
    assert nearest_beam(np.array([el[beam] + frac * min(gaps)]), el)[0] == beam


@pytest.mark.parametrize(("sensor", "beams"), [("vlp16", 16), ("hdl32e", 32), ("hdl64e", 64)])
def test_find_beams_counts_preset_beams_and_rows_follow(sensor: str, beams: int) -> None:
    pts, rows = laser_cloud(sensor)
    found = find_beams(pts)
    assert found is not None and found.n_beams == beams
    np.testing.assert_allclose(found.elevations_deg, get_sensor(sensor).elevations_deg, atol=0.05)
    assert found.width == pytest.approx(1000, rel=0.02)
    np.testing.assert_array_equal(beam_rows(pts, found.elevations_deg, found.origin_height), rows)


def test_find_beams_range_parallax_of_a_two_block_sensor() -> None:
    """HDL-64E-like: the upper block 0.2 m above the origin, the lower one 0.1 m: a point's
    elevation moves by up to 1.5 deg (the road at 4 m), three to five times the beam spacing."""
    heights = np.where(np.arange(64) < 32, 0.2, 0.1)
    pts, rows = laser_cloud("hdl64e", heights=heights)
    found = find_beams(pts)
    assert found is not None and found.n_beams == 64 and found.origin_height == pytest.approx(0.2, abs=0.03)
    assert np.mean(beam_rows(pts, found.elevations_deg, found.origin_height) == rows) > 0.99


def test_beam_rows_sector_without_its_top_beams_keeps_its_rows() -> None:
    pts, rows = laser_cloud("hdl32e")
    sky = (rows < 6) & (np.arctan2(pts[:, 1], pts[:, 0]) > 0)  # half the sectors see no top beams
    found = find_beams(pts)
    assert found is not None
    np.testing.assert_array_equal(beam_rows(pts[~sky], found.elevations_deg, found.origin_height), rows[~sky])


def test_find_beams_none_without_beams() -> None:
    rng = np.random.default_rng(0)
    assert find_beams(rng.uniform(-20, 20, (100, 3)).astype(np.float32)) is None  # too few points
    assert find_beams(rng.uniform(-20, 20, (20_000, 3)).astype(np.float32)) is None  # no beams


def test_find_beams_simulated_campus_frame(tmp_path: Path) -> None:
    from research.simulation import simulate_sequence

    simulate_sequence(tmp_path / "sim", frames=1, seed=1)
    pts = shuffled(read_bin(tmp_path / "sim" / "velodyne" / "000000.bin")[:, :3])[0]
    found = find_beams(pts)
    assert found is not None and found.n_beams == 32 and found.width == 2160
    np.testing.assert_allclose(found.elevations_deg, get_sensor("hdl32e").elevations_deg, atol=0.05)


KITTI = [("kitti_seq00", "000000"), ("kitti_seq00", "000030"), ("kitti_seq00", "000059"),
         ("kitti_seq09", "000003"), ("kitti_seq09", "000010"), ("kitti_seq09", "000014")]


@pytest.mark.real_data
@pytest.mark.parametrize(("seq", "frame"), KITTI)
def test_find_beams_real_kitti_shuffled_is_64_beams(real_data: Path, seq: str, frame: str) -> None:
    """HDL-64E frames without scan order: 64 beams; rows agree with the scan-order rows (measured
    0.953 to 0.998 on these frames; the lower block's lasers differ in height by ~0.3 m)."""
    pts = read_bin(real_data / seq / "velodyne" / f"{frame}.bin")[:, :3]
    truth, found_rings = scan_order_rings(pts, 64)
    assert truth is not None and found_rings == 64
    pts, truth = shuffled(pts, truth)
    found = find_beams(pts)
    assert found is not None and found.n_beams == 64
    assert np.mean(beam_rows(pts, found.elevations_deg, found.origin_height) == truth) > 0.94


@pytest.mark.real_data
def test_find_beams_real_nuscenes_without_ring_is_32_beams(real_data: Path) -> None:
    raw = read_bin(next((real_data / "nuscenes_hdl32e").glob("*.pcd.bin")), record=5)
    pts, ring = shuffled(raw[:, :3], 31 - raw[:, 4].astype(np.int64))
    found = find_beams(pts)
    assert found is not None and found.n_beams == 32
    far = np.hypot(pts[:, 0], pts[:, 1]) >= 1.0  # nuScenes marks no return by a point at the sensor
    rows = beam_rows(pts, found.elevations_deg, found.origin_height)
    assert np.mean(rows[far] == ring[far]) > 0.98


OUSTER = [  # (recording, beams the sensor has, beams that return enough to be counted)
    ("OS-1-128_v2.3.0_1024x10_lb_n3.pcap", 128, 128),
    ("OS-2-128-U1_v2.3.0_1024x10.pcap", 128, 128),
    ("OS-1-32-G_v2.1.1_1024x10.pcap", 32, 32),
    ("OS-0-128-U1_v2.3.0_1024x10.pcap", 128, 122),  # its 6 lowest beams hit the mount: 0-69 points
    ("osf_fw_3.2_10scans.osf", 8, 7),  # its +45 deg beam returns 30 points
]


@pytest.mark.real_data
@pytest.mark.parametrize(("name", "beams", "counted"), OUSTER)
def test_find_beams_real_ouster_shuffled(real_data: Path, name: str, beams: int, counted: int) -> None:
    pytest.importorskip("ouster.sdk")
    from pipeline.io import open_reader

    scan = open_reader(real_data / "ouster" / name).frame(0)
    pts, ring = shuffled(scan.points, scan.ring.astype(np.int64))
    found = find_beams(pts)
    assert found is not None and found.n_beams == counted
    if counted == beams:
        assert np.mean(beam_rows(pts, found.elevations_deg, found.origin_height) == ring) > 0.98
