from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from pipeline.errors import DataError
from pipeline.io import open_reader
from pipeline.odometry import (
    OdometrySettings,
    estimate_poses,
    plane_cloud,
    refine_pair,
    voxel_downsample,
)
from pipeline.scan import Scan
from pipeline.sensors import get_sensor
from tests.pipeline.memory_source import MemorySource


def rigid(x: float, y: float, yaw_deg: float) -> np.ndarray:
    t = np.eye(4)
    a = np.radians(yaw_deg)
    t[:2, :2] = [[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]]
    t[:2, 3] = x, y
    return t


def yaw_deg(t: np.ndarray) -> float:
    return float(np.degrees(np.arctan2(t[1, 0], t[0, 0])))


def street(rng: np.random.Generator, n: int = 40_000) -> np.ndarray:
    """(n, 3) world points on a street: ground, two facades and boxes facing along the street."""
    k = n // 4
    ground = np.column_stack([rng.uniform(-30, 40, k), rng.uniform(-9, 9, k), np.full(k, -1.7)])
    left = np.column_stack([rng.uniform(-30, 40, k), np.full(k, 9.0), rng.uniform(-1.7, 6, k)])
    right = np.column_stack([rng.uniform(-30, 40, k), np.full(k, -9.0), rng.uniform(-1.7, 6, k)])
    boxes = []
    for cx, cy in [(-12, 5), (-3, -6), (6, 4), (15, -5), (24, 6), (33, -4)]:
        m = k // 6
        boxes.append(np.column_stack([np.full(m, cx), cy + rng.uniform(-1, 1, m), rng.uniform(-1.7, 1.5, m)]))
    return np.concatenate([ground, left, right, *boxes])


def synthetic_source(truth: np.ndarray) -> MemorySource:
    rng = np.random.default_rng(0)
    scans = []
    for t in truth:
        world = street(rng, 24_000)  # a fresh sampling of the same surfaces every frame
        local = (world - t[:3, 3]) @ t[:3, :3]  # inv(T) @ p
        local = local[np.linalg.norm(local, axis=1) < 60].astype(np.float32)
        local += rng.normal(0, 0.01, local.shape).astype(np.float32)
        scans.append(Scan(local, np.zeros(len(local), np.float32), np.zeros(len(local), np.int16)))
    return MemorySource(scans, get_sensor("hdl64e"))


def test_estimate_poses_synthetic_street() -> None:
    truth = np.stack([rigid(0.6 * i, 0.02 * i, 0.8 * i) for i in range(5)])
    est = estimate_poses(synthetic_source(truth))
    assert est.shape == (5, 4, 4) and est.dtype == np.float64
    np.testing.assert_allclose(est[0], np.eye(4), atol=1e-9)
    for a in range(4):
        de = np.linalg.inv(est[a]) @ est[a + 1]
        dg = np.linalg.inv(truth[a]) @ truth[a + 1]
        assert np.linalg.norm(de[:3, 3] - dg[:3, 3]) < 0.02
        assert abs(yaw_deg(de) - yaw_deg(dg)) < 0.1


def test_estimate_poses_without_refinement_is_kiss_icp() -> None:
    """KISS-ICP alone (point-to-point, 1 m voxels) is coarser along the street, but on track."""
    truth = np.stack([rigid(0.6 * i, 0.0, 0.0) for i in range(3)])
    coarse = estimate_poses(synthetic_source(truth), settings=OdometrySettings(refine=False))
    assert np.linalg.norm(coarse[2][:3, 3] - [1.2, 0.0, 0.0]) < 0.25


def test_estimate_poses_empty_source_raises() -> None:
    with pytest.raises(DataError, match="no frames"):
        estimate_poses(MemorySource([], get_sensor("hdl64e")))


def test_refine_pair_recovers_offset_on_planes() -> None:
    rng = np.random.default_rng(3)
    world = street(rng, 20_000)
    target = plane_cloud(voxel_downsample(world, 0.2))
    offset = rigid(0.05, -0.03, 0.3)
    source = (world - offset[:3, 3]) @ offset[:3, :3]  # the same surfaces seen from `offset`
    got = refine_pair(voxel_downsample(source, 0.4), target, np.eye(4), OdometrySettings())
    assert got is not None
    np.testing.assert_allclose(got[:3, 3], offset[:3, 3], atol=5e-3)
    assert yaw_deg(got) == pytest.approx(0.3, abs=0.02)


def test_voxel_downsample_one_point_per_voxel() -> None:
    pts = np.array([[0.01, 0.01, 0.01], [0.05, 0.02, 0.0], [0.3, 0.0, 0.0], [-0.01, 0.0, 0.0]])
    np.testing.assert_array_equal(voxel_downsample(pts, 0.1), pts[[0, 2, 3]])


def test_estimate_poses_kitti_seq09_matches_ground_truth(kitti_seq09: Path) -> None:
    """KITTI seq 09 frames 10-14: each frame-to-frame motion within 5% of translation and 0.3 deg yaw."""
    seq = open_reader(kitti_seq09)
    est = estimate_poses(seq)
    for a in range(len(seq) - 1):
        de = np.linalg.inv(est[a]) @ est[a + 1]
        dg = np.linalg.inv(seq.poses[a]) @ seq.poses[a + 1]
        err = np.linalg.norm(de[:3, 3] - dg[:3, 3]) / np.linalg.norm(dg[:3, 3])
        assert err < 0.05, (a, err)
        assert abs(yaw_deg(de) - yaw_deg(dg)) < 0.3, a
