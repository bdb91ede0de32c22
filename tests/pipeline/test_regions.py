from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from pipeline.regions import (
    Box,
    HalfSpace,
    Prism,
    ScreenLasso,
    points_in_polygon,
    quaternion_matrix,
    select_points,
)

coords = st.floats(-50, 50, allow_nan=False, allow_infinity=False)


@settings(max_examples=50, deadline=None)
@given(st.lists(st.tuples(coords, coords, coords), min_size=1, max_size=50), st.floats(-np.pi, np.pi))
def test_regions_box_rotated_about_z_equals_points_rotated_back(pts, yaw):
    pts = np.array(pts)
    wxyz = np.array([np.cos(yaw / 2), 0, 0, np.sin(yaw / 2)])
    box = Box(np.array([1.0, 2.0, 0.0]), np.array([10.0, 4.0, 3.0]), wxyz)
    c, s = np.cos(-yaw), np.sin(-yaw)
    local = (pts - box.center) @ np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]]).T
    expect = (np.abs(local[:, 0]) <= 5) & (np.abs(local[:, 1]) <= 2) & (np.abs(local[:, 2]) <= 1.5)
    assert np.array_equal(select_points(box, pts), expect)


def test_regions_quaternion_matrix_is_a_rotation():
    r = quaternion_matrix(np.array([0.3, -0.2, 0.8, 0.1]))
    assert np.allclose(r @ r.T, np.eye(3)) and np.isclose(np.linalg.det(r), 1.0)


def test_regions_half_space_and_prism():
    pts = np.array([[0.0, 0, 0], [2, 0, 0], [2, 0, 5], [-1, 0, 0]])
    assert select_points(HalfSpace(np.array([1.0, 0, 0]), 1.0), pts).tolist() == [False, True, True, False]
    square = np.array([[1.0, -1], [3, -1], [3, 1], [1, 1]])
    assert select_points(Prism(square, -1.0, 1.0), pts).tolist() == [False, True, False, False]


def test_regions_points_in_concave_polygon():
    ell = np.array([[0.0, 0], [2, 0], [2, 1], [1, 1], [1, 2], [0, 2]])
    xy = np.array([[0.5, 0.5], [1.5, 0.5], [1.5, 1.5], [0.5, 1.5], [3, 3]])
    assert points_in_polygon(xy, ell).tolist() == [True, True, False, True, False]


def test_regions_screen_lasso_with_top_down_orthographic_camera_equals_prism():
    """An orthographic camera looking down maps world x, y to NDC x/10, y/10: the lasso then
    selects what the prism of the scaled polygon selects (any height)."""
    rng = np.random.default_rng(0)
    pts = rng.uniform(-12, 12, size=(500, 3))
    clip = np.diag([0.1, 0.1, -0.01, 1.0])
    ndc_poly = np.array([[-0.5, -0.5], [0.6, -0.4], [0.1, 0.7]])
    lasso = select_points(ScreenLasso(ndc_poly, clip), pts)
    prism = select_points(Prism(ndc_poly * 10, -1e9, 1e9), pts)
    assert lasso.any() and np.array_equal(lasso, prism)


def test_regions_screen_lasso_ignores_points_behind_the_camera():
    clip = np.array([[1.0, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, -1, 0]])  # w = -z: camera looks down -z
    pts = np.array([[0.1, 0.1, -1.0], [0.1, 0.1, 1.0]])
    square = np.array([[-1.0, -1], [1, -1], [1, 1], [-1, 1]])
    assert select_points(ScreenLasso(square, clip), pts).tolist() == [True, False]
