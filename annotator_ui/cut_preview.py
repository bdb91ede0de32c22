"""What the cut box would take, before it cuts: the shown track's points of this frame inside the
box, counted and highlighted (/cut/preview), and the gizmo's size from the track's extent."""

from __future__ import annotations

import numpy as np

PREVIEW_COLOUR = (255, 40, 40)


def inside_box(points: np.ndarray, centre: np.ndarray, R: np.ndarray, size: np.ndarray) -> np.ndarray:
    """(N,) bool: which of the (N, 3) points lie in the box (centre (3,), rotation (3, 3) box ->
    scene, full edge lengths (3,)), all in the same frame."""
    assert points.ndim == 2 and points.shape[1] == 3, points.shape
    local = (points.astype(np.float64) - centre) @ R  # rows: the points in the box's axes
    return np.all(np.abs(local) <= np.asarray(size, np.float64) / 2.0, axis=1)


def gizmo_scale(points: np.ndarray) -> float:
    """Arrows about as long as the track is wide (0.5-8 m), so they sit on it at any distance."""
    if len(points) == 0:
        return 1.5
    return float(np.clip(0.6 * np.ptp(points, axis=0).max(), 0.5, 8.0))


def preview_text(n_inside: int, n_track: int) -> str:
    if n_track == 0:
        return "Cut preview: the track has no points in this frame"
    return f"Cut preview: **{n_inside}** of {n_track} track points in this frame are inside the box (red)"
