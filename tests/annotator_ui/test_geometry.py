"""Picking with the click ray and moving a track's path into a frame."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from annotator_ui.geometry import pick_point, polyline_segments, pose_matrix, world_to_lidar


def test_pick_point_returns_the_point_on_the_ray():
    pts = np.array([[10, 0, 0], [10, 1, 0], [10, -1, 0]], np.float32)
    assert pick_point(pts, np.zeros(3), np.array([1.0, 0.1, 0.0])) == 1


def test_pick_point_prefers_the_near_object_over_the_wall_behind():
    rng = np.random.default_rng(0)
    wall = np.column_stack([np.full(500, 30.0), rng.uniform(-5, 5, 500), rng.uniform(0, 3, 500)])
    obj = np.array([[10.0, 0.02, 1.0]])
    pts = np.vstack([wall, obj]).astype(np.float32)
    assert pick_point(pts, np.array([0, 0, 1.0]), np.array([1.0, 0, 0])) == len(pts) - 1


def test_pick_point_misses_when_nothing_is_near_the_ray():
    pts = np.array([[10, 0, 0]], np.float32)
    assert pick_point(pts, np.zeros(3), np.array([0.0, 1.0, 0.0])) == -1
    assert pick_point(pts, np.zeros(3), np.array([-1.0, 0.0, 0.0])) == -1  # behind the camera


def test_pick_point_respects_the_candidate_mask():
    pts = np.array([[10, 0, 0], [10, 0.1, 0]], np.float32)
    assert pick_point(pts, np.zeros(3), np.array([1.0, 0, 0]), candidates=np.array([False, True])) == 1


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 199), st.floats(-50, 50), st.floats(-50, 50), st.floats(0, 20))
def test_pick_point_a_ray_through_a_point_picks_it_or_a_nearer_one_on_the_ray(i, ox, oy, oz):
    rng = np.random.default_rng(1)
    pts = rng.uniform(-40, 40, (200, 3)).astype(np.float32)
    origin = np.array([ox, oy, oz])
    direction = pts[i].astype(np.float64) - origin
    if np.linalg.norm(direction) < 1.0:
        return
    j = pick_point(pts, origin, direction)
    assert j >= 0
    d = direction / np.linalg.norm(direction)
    v = pts[j] - origin
    depth = v @ d
    assert depth <= np.linalg.norm(direction) + 1e-3  # never a point behind the target


def test_world_to_lidar_inverts_the_pose():
    T = np.eye(4)
    T[:3, :3] = [[0, -1, 0], [1, 0, 0], [0, 0, 1]]
    T[:3, 3] = [5, 2, 0.5]
    p_lidar = np.array([[1.0, 2.0, 3.0]])
    p_world = (T[:3, :3] @ p_lidar.T).T + T[:3, 3]
    np.testing.assert_allclose(world_to_lidar(p_world, pose_matrix(T.reshape(-1).tolist())), p_lidar, atol=1e-5)
    assert world_to_lidar(p_world, T).dtype == np.float32


def test_polyline_segments_join_consecutive_vertices():
    segs = polyline_segments(np.arange(9, dtype=np.float32).reshape(3, 3))
    assert segs.shape == (2, 2, 3) and (segs[0, 1] == segs[1, 0]).all()
    assert polyline_segments(np.zeros((1, 3))).shape == (0, 2, 3)


def test_geometry_clip_from_scene_puts_the_look_at_point_at_the_screen_centre():
    from annotator_ui.geometry import clip_from_scene, matrix_wxyz, rect_polygon_ndc
    from pipeline.regions import ScreenLasso, quaternion_matrix

    # camera at (0, -10, 0) looking along +y (scene), image up = scene +z
    R = np.array([[1.0, 0, 0], [0, 0, 1], [0, -1, 0]])  # columns: camera x, y, z in the scene
    wxyz = matrix_wxyz(R)
    assert np.allclose(quaternion_matrix(wxyz), R)
    clip = clip_from_scene(np.array([0.0, -10, 0]), wxyz, fov=np.pi / 2, aspect=2.0)
    pts = np.array([[0.0, 0, 0], [0, 0, 5], [5, 0, 0], [0, -20, 0]])  # centre, up, right, behind
    h = np.c_[pts, np.ones(4)] @ clip.T
    ndc = h[:, :2] / h[:, 3:]
    assert np.allclose(ndc[0], [0, 0]) and np.allclose(ndc[1], [0, 0.5]) and np.allclose(ndc[2], [0.25, 0])
    upper_right = rect_polygon_ndc((0.5, 0.0), (1.0, 0.5))  # screen top-right quarter
    inside = ScreenLasso(upper_right, clip).contains(np.array([[1.0, 0, 1], [1.0, 0, -1], [0, -20, 0]]))
    assert inside.tolist() == [True, False, False]
