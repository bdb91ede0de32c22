"""The simulated operator's lasso on the top view: where to draw a ground region next.

The operator looks at the ground layer of every frame at once (the points the export labels as
ground or by a region), knows the true class of each point it sees, and draws the polygon that
would put the most of them right: around a connected area of grid cells whose points are mostly
of one class, traced along its outline as a person traces a sidewalk's curb or a lawn's edge.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from pipeline.classes import UNLABELLED
from pipeline.regions import points_in_polygon

CELL = 0.5  # m: the top view's grid the operator reads areas from
MAX_VERTICES = 1000  # the API's limit
CANDIDATES = 3  # outlines tried per class, largest estimated gain first
UP = 8  # pixels per cell side when tracing an outline


@dataclass(frozen=True)
class Lasso:
    polygon: np.ndarray  # (K, 2) world x, y
    class_: int
    gain: int  # points it puts right minus points it puts wrong, among those seen


def _outline(mask: np.ndarray, origin: np.ndarray) -> np.ndarray | None:
    """The outer outline of a cell mask as a world polygon along the cells' outer edges (to
    1 / (2 UP) of a cell: the contour runs through the centres of the edge pixels of the mask
    drawn UP times larger)."""
    big = np.kron(mask, np.ones((UP, UP), np.uint8))
    contours, _ = cv2.findContours(big, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
    if not contours:
        return None
    c = max(contours, key=cv2.contourArea)
    eps = 1.0
    poly = cv2.approxPolyDP(c, eps, True)
    while len(poly) > MAX_VERTICES:
        eps *= 2
        poly = cv2.approxPolyDP(c, eps, True)
    if len(poly) < 3:
        return None
    rc = poly[:, 0, ::-1].astype(np.float64)  # (row, col) = (x, y) pixels
    return origin + ((rc + 0.5) / UP - 1) * CELL  # the grid has a margin of one cell


def _gain(xy: np.ndarray, true: np.ndarray, current: np.ndarray, polygon: np.ndarray, cls: int) -> int:
    inside = points_in_polygon(xy, polygon)
    t, c = true[inside], current[inside]
    return int(((t == cls) & (c != cls)).sum() - ((c == t) & (t != cls)).sum())


def plan(xy: np.ndarray, true: np.ndarray, current: np.ndarray, n_classes: int) -> Lasso | None:
    """The best lasso over these seen points ((N, 2) world x, y; true and current class per
    point, UNLABELLED where unknown), or None when nothing is wrong."""
    known = true != UNLABELLED
    xy, true, current = xy[known], true[known], current[known]
    wrong = true != current
    if not wrong.any():
        return None
    origin = xy.min(0)
    ij = np.floor((xy - origin) / CELL).astype(np.int64) + 1  # a margin of one cell for the outline
    h, w = ij.max(0) + 2
    cell = ij[:, 0] * w + ij[:, 1]
    counts = np.bincount(cell * n_classes + true, minlength=h * w * n_classes).reshape(h * w, n_classes)
    major = counts.argmax(1)
    best: Lasso | None = None
    for cls in np.unique(true[wrong]):
        mask = ((major == cls) & (counts.sum(1) > 0)).reshape(h, w).astype(np.uint8)
        n, comp = cv2.connectedComponents(mask, connectivity=8)
        comp_of_point = comp.ravel()[cell]
        estimate = np.bincount(comp_of_point[wrong & (true == cls)], minlength=n)
        estimate[0] = 0
        for k in np.argsort(-estimate)[:CANDIDATES]:
            if estimate[k] == 0 or (best is not None and estimate[k] <= best.gain):
                break
            polygon = _outline((comp == k).astype(np.uint8), origin)
            if polygon is None:
                continue
            gain = _gain(xy, true, current, polygon, int(cls))
            if best is None or gain > best.gain:
                best = Lasso(polygon, int(cls), gain)
    return best
