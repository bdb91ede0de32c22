"""Viewer-side geometry: picking a point with the click ray, and a track's path in a frame.

The scene is the current frame's lidar frame (sensor at the origin, x forward, z up), so the
click ray viser reports in scene coordinates is already in the lidar frame.
"""

from __future__ import annotations

import numpy as np

PICK_MAX_ANGLE = 0.03  # rad (~1.7 deg): a click farther than this from every point picks nothing
PICK_DEPTH_TOLERANCE = 0.004  # rad: among points this close to the best angle, the nearest wins


def pick_point(
    points: np.ndarray,
    ray_origin: np.ndarray,
    ray_direction: np.ndarray,
    candidates: np.ndarray | None = None,
    max_angle: float = PICK_MAX_ANGLE,
) -> int:
    """Index of the point the click ray hits best, or -1.

    points: (N, 3) float; ray_origin, ray_direction: (3,); candidates: optional (N,) bool mask of
    pickable points. The distance to the ray is measured as the angle seen from the ray origin
    (perpendicular distance / depth), which is what a click's pixel offset means; among points
    within `PICK_DEPTH_TOLERANCE` of the best angle the one nearest the camera wins, so a click on
    an object does not pick the wall behind it."""
    pts = np.asarray(points, np.float64)
    assert pts.ndim == 2 and pts.shape[1] == 3, pts.shape
    o = np.asarray(ray_origin, np.float64).reshape(3)
    d = np.asarray(ray_direction, np.float64).reshape(3)
    norm = np.linalg.norm(d)
    if not np.isfinite(norm) or norm == 0 or len(pts) == 0:
        return -1
    d = d / norm
    v = pts - o  # (N, 3)
    depth = v @ d  # (N,) distance along the ray
    perp2 = np.maximum(np.einsum("ij,ij->i", v, v) - depth * depth, 0.0)
    ok = depth > 1e-3
    if candidates is not None:
        ok &= np.asarray(candidates, bool)
    if not ok.any():
        return -1
    idx = np.flatnonzero(ok)
    angle = np.sqrt(perp2[idx]) / depth[idx]
    best = float(angle.min())
    if best > max_angle:
        return -1
    near = angle <= best + PICK_DEPTH_TOLERANCE
    return int(idx[near][np.argmin(depth[idx][near])])


def pose_matrix(pose: list[float] | None) -> np.ndarray:
    """A frame's `pose` (T_world_lidar, 16 floats row-major, or None) as a (4, 4) float64 matrix."""
    if pose is None:
        return np.eye(4)
    T = np.asarray(pose, np.float64)
    assert T.size == 16, T.size
    return T.reshape(4, 4)


def world_to_lidar(points_world: np.ndarray, T_world_lidar: np.ndarray) -> np.ndarray:
    """(M, 3) world points -> (M, 3) float32 points in the lidar frame of pose T_world_lidar."""
    p = np.asarray(points_world, np.float64).reshape(-1, 3)
    T_lidar_world = np.linalg.inv(T_world_lidar)
    return (p @ T_lidar_world[:3, :3].T + T_lidar_world[:3, 3]).astype(np.float32)


def polyline_segments(points: np.ndarray) -> np.ndarray:
    """(M, 3) path vertices -> (M-1, 2, 3) line segments joining consecutive vertices."""
    p = np.asarray(points, np.float32).reshape(-1, 3)
    if len(p) < 2:
        return np.zeros((0, 2, 3), np.float32)
    return np.stack([p[:-1], p[1:]], axis=1)


def clip_from_scene(position: np.ndarray, wxyz: np.ndarray, fov: float, aspect: float) -> np.ndarray:
    """(4, 4) matrix taking homogeneous scene points to clip coordinates of a viser camera:
    `position` and `wxyz` are R_scene_camera in OpenCV axes (x right, y down, z forward), `fov`
    the vertical field of view (rad), `aspect` width / height. NDC x = clip x / w (right),
    y = clip y / w (up), w = depth along the view; only x, y and w carry meaning."""
    from pipeline.regions import quaternion_matrix

    R = quaternion_matrix(np.asarray(wxyz, np.float64))
    view = np.eye(4)
    view[:3, :3], view[:3, 3] = R.T, -R.T @ np.asarray(position, np.float64)
    t = np.tan(fov / 2.0)
    proj = np.array([[1 / (t * aspect), 0, 0, 0], [0, -1 / t, 0, 0], [0, 0, 1, 0], [0, 0, 1, 0]], np.float64)
    return proj @ view


def rect_polygon_ndc(screen_min: tuple[float, float], screen_max: tuple[float, float]) -> np.ndarray:
    """(4, 2) NDC corners of a screen rectangle given in OpenCV image coordinates (0..1, y down)."""
    (u0, v0), (u1, v1) = screen_min, screen_max
    return np.array([[2 * u - 1, 1 - 2 * v] for u, v in ((u0, v0), (u1, v0), (u1, v1), (u0, v1))], np.float64)


def matrix_wxyz(R: np.ndarray) -> np.ndarray:
    """(4,) unit quaternion (w, x, y, z) of a (3, 3) rotation matrix."""
    m = np.asarray(R, np.float64)
    w = np.sqrt(max(0.0, 1 + m[0, 0] + m[1, 1] + m[2, 2])) / 2
    x = np.copysign(np.sqrt(max(0.0, 1 + m[0, 0] - m[1, 1] - m[2, 2])) / 2, m[2, 1] - m[1, 2])
    y = np.copysign(np.sqrt(max(0.0, 1 - m[0, 0] + m[1, 1] - m[2, 2])) / 2, m[0, 2] - m[2, 0])
    z = np.copysign(np.sqrt(max(0.0, 1 - m[0, 0] - m[1, 1] + m[2, 2])) / 2, m[1, 0] - m[0, 1])
    q = np.array([w, x, y, z])
    return q / np.linalg.norm(q)
