"""The background cloud's level of detail, and its colours kept per frame version.

A real KITTI frame holds ~124k points, most of them on the ground within 10 m of the sensor
(the beams crowd there); the demo's ~60k. Software WebGL (and a laptop's GPU, less so) pays per
point drawn, and the browser decodes every point sent. So the background cloud keeps one point
per VOXEL_M cube (the first in scan order): the crowded near field is thinned and the sparse far
field, where each point matters, is kept. Over `budget` the survivors are thinned evenly. The
reviewed track is drawn from all of its points apart from this cloud (scene_view's
/frame/track), so the level of detail never thins what the operator judges.

On kitti_seq00 frame 0: 124,668 points -> 31,583 voxels of 0.2 m -> the budget of 16,384; a demo
frame: 60,945 -> 17,694 -> 16,384. A real frame then costs the browser what a demo frame does
(docs/annotator.md has the measurements).
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from collections.abc import Callable

import numpy as np

VOXEL_M = 0.2
MAX_CLOUD_POINTS = 16_384


def lod(points: np.ndarray, budget: int = MAX_CLOUD_POINTS, voxel_m: float = VOXEL_M) -> np.ndarray:
    """(M,) ascending indices into `points` (N, 3) of the background cloud, M <= budget: one
    point per `voxel_m` cube (0 = no voxel thinning), then an even thinning to `budget`.
    Non-finite points are left out."""
    assert points.ndim == 2 and points.shape[1] == 3, points.shape
    keep = np.flatnonzero(np.isfinite(points).all(axis=1))
    if voxel_m > 0 and len(keep):
        cells = np.floor(points[keep] / voxel_m).astype(np.int64)
        cells -= cells.min(axis=0)
        span = cells.max(axis=0) + 1
        key = (cells[:, 0] * span[1] + cells[:, 1]) * span[2] + cells[:, 2]  # exact: lidar ranges fit int64
        _, first = np.unique(key, return_index=True)
        keep = keep[np.sort(first)]
    if len(keep) > budget:
        keep = keep[np.linspace(0, len(keep) - 1, budget).astype(np.int64)]
    return keep


class CloudMemo:
    """(frame id, ETag, colour mode) -> (indices, colours) of the background cloud, for the last
    few frames: the prefetch fills it for the next track's frame, the draw reads it. Thread-safe."""

    def __init__(self, size: int = 4) -> None:
        self.size = size
        self._lock = threading.Lock()
        self._items: OrderedDict[tuple[int, str, str], tuple[np.ndarray, np.ndarray]] = OrderedDict()

    def get(self, key: tuple[int, str, str], make: Callable[[], tuple[np.ndarray, np.ndarray]]) -> tuple[np.ndarray, np.ndarray]:
        with self._lock:
            hit = self._items.get(key)
            if hit is not None:
                self._items.move_to_end(key)
                return hit
        value = make()  # outside the lock: a draw does not wait for a prefetch of another frame
        with self._lock:
            self._items[key] = value
            while len(self._items) > self.size:
                self._items.popitem(last=False)
        return value
