from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from pipeline.config import RangeImageConfig
from pipeline.range_image import azimuth_columns, column_azimuth, project
from pipeline.scan import Scan
from pipeline.sensors import PRESETS

SENSOR = PRESETS["hdl32e"]


def _scan(rng: np.random.Generator, n: int) -> Scan:
    pts = rng.uniform(-40, 40, size=(n, 3)).astype(np.float32)
    ring = rng.integers(0, SENSOR.n_rings, size=n).astype(np.int16)
    return Scan(pts, rng.uniform(0, 1, n).astype(np.float32), ring)


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 10_000), n=st.integers(0, 3000), width=st.sampled_from([64, 360, 2160]))
def test_range_image_projection_is_a_bijection_on_kept_points(seed, n, width):
    scan = _scan(np.random.default_rng(seed), n)
    img = project(scan, SENSOR, RangeImageConfig(width=width, min_range=0.5, max_range=80.0))
    owners = img.index[img.index >= 0]
    # each owning point appears once, sits on its own pixel, and is the nearest point of that pixel
    assert len(np.unique(owners)) == len(owners)
    assert (img.index[img.row[owners], img.col[owners]] == owners).all()
    kept = np.flatnonzero(img.kept)
    assert set(np.unique(img.row[kept].astype(np.int64) * width + img.col[kept])) == set(
        np.flatnonzero(img.index.ravel() >= 0)
    )
    assert (img.range[img.row[kept], img.col[kept]] <= img.point_range[kept] + 1e-6).all()


def test_range_image_columns_wrap_behind_and_face_forward():
    w = 2160
    pts = np.array([[10, 0, 0], [0, 10, 0], [0, -10, 0], [-10, 1e-3, 0], [-10, -1e-3, 0]], np.float32)
    cols = azimuth_columns(pts, w)
    assert cols[0] == w // 2 and cols[1] == w // 4 and cols[2] == 3 * w // 4
    assert {int(cols[3]), int(cols[4])} == {0, w - 1}


def test_range_image_column_azimuth_inverts_columns():
    w = 1024
    cols = np.arange(w)
    az = column_azimuth(cols, w)
    pts = np.stack([np.cos(az), np.sin(az), np.zeros(w)], axis=1).astype(np.float32)
    assert (azimuth_columns(pts, w) == cols).all()


def test_range_image_empty_scan_gives_empty_image():
    scan = Scan(np.zeros((0, 3), np.float32), np.zeros(0, np.float32), np.zeros(0, np.int16))
    img = project(scan, SENSOR)
    assert img.index.shape == (32, 2160) and (img.index == -1).all()
