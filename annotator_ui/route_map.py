"""A small top view of the sequence's route: where the sensor drove (grey), the frames the track
is seen from (orange) and where the track is (white), so an operator knows where on the route the
shown track lies."""

from __future__ import annotations

from typing import Any

import numpy as np

from annotator_ui.geometry import pose_matrix

SIZE = 160
ROUTE = (110, 110, 110)
SEEN_FROM = (255, 140, 0)
TRACK = (255, 255, 255)


def _dots(img: np.ndarray, rows: np.ndarray, cols: np.ndarray, colour: tuple[int, int, int], r: int) -> None:
    n = img.shape[0]
    for dr in range(-r, r + 1):
        for dc in range(-r, r + 1):
            img[np.clip(rows + dr, 0, n - 1), np.clip(cols + dc, 0, n - 1)] = colour


def route_image(track: dict[str, Any], frames: dict[int, dict[str, Any]], size: int = SIZE) -> np.ndarray:
    """(size, size, 3) uint8: the route's sensor positions (x right, y up, equal scale), the frames
    the track spans and the track's centroids."""
    img = np.full((size, size, 3), 24, np.uint8)
    order = sorted(frames)
    sensor = np.array([pose_matrix(frames[i].get("pose"))[:2, 3] for i in order], np.float64).reshape(-1, 2)
    segs = track.get("segments", [])
    centroids = np.array([s["centroid_world"][:2] for s in segs], np.float64).reshape(-1, 2)
    every = np.vstack([sensor, centroids])
    if len(every) == 0:
        return img
    lo, span = every.min(0), max(float(np.ptp(every, axis=0).max()), 1.0) * 1.1
    lo = lo - (span - np.ptp(every, axis=0)) / 2

    def rc(xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        uv = ((xy - lo) / span * (size - 1)).astype(np.int64).clip(0, size - 1)
        return size - 1 - uv[:, 1], uv[:, 0]

    _dots(img, *rc(sensor), ROUTE, 0)
    seen = np.isin(order, [s["frame_index"] for s in segs])
    _dots(img, *rc(sensor[seen]), SEEN_FROM, 1)
    _dots(img, *rc(centroids), TRACK, 1)
    return img
