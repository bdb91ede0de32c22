"""Regions that select points for a track split, all in the world frame.

A region answers one question: which of these (N, 3) world points lie inside it. Kinds:

- `Box`: centre, size (x, y, z extents in its own axes) and orientation (unit quaternion
  w, x, y, z, as viser's transform controls report it); the box's axes are R @ e_i.
- `HalfSpace`: points p with normal . p >= offset (a cutting plane; the normal need not be unit).
- `Prism`: a polygon in the world x-y plane, extruded from z_min to z_max (a lasso drawn in
  the top view).
- `ScreenLasso`: a polygon in normalised device coordinates (x right, y up, both -1..1) and the
  4x4 `clip_from_world` matrix of the camera it was drawn with; a point is inside when it lies in
  front of the camera (clip w > 0), between its near and far planes (-w <= clip z <= w: a
  projection whose z row equals its w row, as the viewer's, has no such planes) and its
  projection falls inside the polygon.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


def quaternion_matrix(wxyz: np.ndarray) -> np.ndarray:
    """(3, 3) rotation of a quaternion (w, x, y, z); normalised first."""
    w, x, y, z = np.asarray(wxyz, np.float64) / np.linalg.norm(wxyz)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def points_in_polygon(xy: np.ndarray, polygon: np.ndarray) -> np.ndarray:
    """(N,) bool: even-odd rule of (N, 2) points against a (K, 2) polygon (K >= 3, not closed)."""
    assert xy.ndim == 2 and xy.shape[1] == 2 and polygon.ndim == 2 and polygon.shape[1] == 2
    inside = np.zeros(len(xy), bool)
    x, y = xy[:, 0], xy[:, 1]
    for (x0, y0), (x1, y1) in zip(polygon, np.roll(polygon, -1, axis=0), strict=True):
        crosses = (y0 > y) != (y1 > y)
        with np.errstate(divide="ignore", invalid="ignore"):
            x_at = x0 + (y - y0) * (x1 - x0) / (y1 - y0)
        inside ^= crosses & (x < x_at)
    return inside


@dataclass(frozen=True)
class Box:
    center: np.ndarray  # (3,)
    size: np.ndarray  # (3,) full extents along the box axes
    wxyz: np.ndarray  # (4,) orientation

    def contains(self, points: np.ndarray) -> np.ndarray:
        local = (points - self.center) @ quaternion_matrix(self.wxyz)  # rows: R^T (p - c)
        return np.all(np.abs(local) <= np.asarray(self.size) / 2.0, axis=1)


@dataclass(frozen=True)
class HalfSpace:
    normal: np.ndarray  # (3,)
    offset: float

    def contains(self, points: np.ndarray) -> np.ndarray:
        return points @ np.asarray(self.normal, np.float64) >= self.offset


@dataclass(frozen=True)
class Prism:
    polygon: np.ndarray  # (K, 2) world x, y
    z_min: float
    z_max: float

    def contains(self, points: np.ndarray) -> np.ndarray:
        z = points[:, 2]
        return points_in_polygon(points[:, :2], self.polygon) & (z >= self.z_min) & (z <= self.z_max)


@dataclass(frozen=True)
class ScreenLasso:
    polygon: np.ndarray  # (K, 2) normalised device coordinates
    clip_from_world: np.ndarray  # (4, 4)

    def contains(self, points: np.ndarray) -> np.ndarray:
        homo = np.concatenate([points, np.ones((len(points), 1))], axis=1) @ self.clip_from_world.T  # (N, 4)
        w = homo[:, 3]
        front = (w > 1e-9) & (np.abs(homo[:, 2]) <= w * (1.0 + 1e-9))
        ndc = homo[:, :2] / np.where(front, w, 1.0)[:, None]
        return front & points_in_polygon(ndc, self.polygon)


def with_depth_planes(clip_from_world: np.ndarray, near: float, far: float) -> np.ndarray:
    """(4, 4) `clip_from_world` whose clip z is -w at depth `near` and w at `far` (depth: its clip
    w), so that a `ScreenLasso` drawn with it holds only the points between (0 < near < far)."""
    out = np.array(clip_from_world, np.float64)
    a, b = (far + near) / (far - near), -2.0 * far * near / (far - near)
    out[2] = a * out[3]
    out[2, 3] += b
    return out


Region = Box | HalfSpace | Prism | ScreenLasso


def select_points(region: Region, points_world: np.ndarray) -> np.ndarray:
    """(N,) bool: the (N, 3) world points inside `region`."""
    assert points_world.ndim == 2 and points_world.shape[1] == 3, points_world.shape
    return region.contains(points_world.astype(np.float64))
