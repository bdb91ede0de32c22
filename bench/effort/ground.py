"""The simulated operator's lasso on the top view: where to draw a region next.

The operator looks at every frame at once, knows the true class of each point it sees, and draws
the polygon that would put the most of them right: around a connected area of grid cells whose
points are mostly of one class, traced along its outline as a person traces a sidewalk's curb or
a lawn's edge. `plan` draws over the ground layer (the points the export labels as ground or by a
region; the region labels ground points); `plan_prism` over every point, with a height range
(the region labels every point inside the prism: a hedge, a fence grown into it).
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

import cv2
import numpy as np

from pipeline.classes import UNLABELLED
from pipeline.propagation import GroundRegion

CELL = 0.5  # m: the top view's grid the operator reads areas from
MAX_VERTICES = 1000  # the API's limit
CANDIDATES = 3  # outlines tried per class, largest estimated gain first
UP = 8  # pixels per cell side when tracing an outline
PRISM_VERTICES = 32  # a hedge or a fence traced in a few dozen clicks
PRISM_CELLS = (CELL, 0.35)  # m: the grids a prism's area is read from
BOTTOMS = (1.0, 5.0, 10.0, 25.0)  # percentiles of the class's heights in the area a prism's bottom is tried at
TOP_PERCENTILE = 99.0  # of the same heights: its top


@dataclass(frozen=True)
class Lasso:
    polygon: np.ndarray  # (K, 2) world x, y
    class_: int
    gain: int  # points it puts right minus points it puts wrong, among those seen
    heights: tuple[float, float] | None = None  # world z low, high: every point between (None: ground points)


def _outline(mask: np.ndarray, origin: np.ndarray, max_vertices: int = MAX_VERTICES,
             cell_size: float = CELL) -> np.ndarray | None:
    """The outer outline of a cell mask as a world polygon along the cells' outer edges (to
    1 / (2 UP) of a cell: the contour runs through the centres of the edge pixels of the mask
    drawn UP times larger), simplified to at most `max_vertices`."""
    big = np.kron(mask, np.ones((UP, UP), np.uint8))
    contours, _ = cv2.findContours(big, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
    if not contours:
        return None
    c = max(contours, key=cv2.contourArea)
    eps = 1.0
    poly = cv2.approxPolyDP(c, eps, True)
    while len(poly) > max_vertices:
        eps *= 2
        poly = cv2.approxPolyDP(c, eps, True)
    if len(poly) < 3:
        return None
    rc = poly[:, 0, ::-1].astype(np.float64)  # (row, col) = (x, y) pixels
    return origin + ((rc + 0.5) / UP - 1) * cell_size  # the grid has a margin of one cell


def _gain(inside: np.ndarray, true: np.ndarray, current: np.ndarray, cls: int) -> int:
    t, c = true[inside], current[inside]
    return int(((t == cls) & (c != cls)).sum() - ((c == t) & (t != cls)).sum())


def _areas(xy: np.ndarray, true: np.ndarray, wrong: np.ndarray, area: np.ndarray, n_classes: int,
           cell_size: float = CELL) -> Iterator[tuple[int, int, np.ndarray, np.ndarray, np.ndarray]]:
    """Per class of the wrong points, the connected areas of grid cells whose `area` points are
    mostly of that class, largest first by the wrong points of that class they hold: (class,
    that estimate, the cell mask, its grid origin, which points lie in its cells)."""
    origin, cell, counts = class_grid(xy, true, area, n_classes, cell_size)
    major, seen = counts.argmax(2), counts.sum(2) > 0
    for cls in np.unique(true[wrong]):
        mask = ((major == cls) & seen).astype(np.uint8)
        for estimate, comp, in_area in components(mask, cell, wrong & (true == cls)):
            yield int(cls), estimate, comp, origin, in_area


def class_grid(xy: np.ndarray, true: np.ndarray, area: np.ndarray, n_classes: int,
               cell_size: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A grid of `cell_size` over (N, 2) points with a margin of one cell (for the outline): its
    origin, each point's cell (flat index) and (H, W, n_classes) counts of the `area` points' true
    classes per cell."""
    origin = xy.min(0)
    ij = np.floor((xy - origin) / cell_size).astype(np.int64) + 1
    h, w = ij.max(0) + 2
    cell = ij[:, 0] * w + ij[:, 1]
    counts = np.bincount(cell[area] * n_classes + true[area], minlength=h * w * n_classes)
    return origin, cell, counts.reshape(h, w, n_classes)


def components(mask: np.ndarray, cell: np.ndarray, wrong: np.ndarray) -> Iterator[tuple[int, np.ndarray, np.ndarray]]:
    """The `CANDIDATES` connected areas of a cell mask that hold the most `wrong` points (each
    point in cell `cell`, flat index), largest first: (that count, the area's mask, which points
    lie in it)."""
    n, comp = cv2.connectedComponents(mask, connectivity=8)
    comp_of_point = comp.ravel()[cell]
    estimate = np.bincount(comp_of_point[wrong], minlength=n)
    estimate[0] = 0
    for k in np.argsort(-estimate)[:CANDIDATES]:
        if estimate[k] == 0:
            break
        yield int(estimate[k]), (comp == k).astype(np.uint8), comp_of_point == k


def plan(xy: np.ndarray, true: np.ndarray, current: np.ndarray, n_classes: int) -> Lasso | None:
    """The best lasso over these seen points ((N, 2) world x, y; true and current class per
    point, UNLABELLED where unknown), or None when nothing is wrong."""
    known = true != UNLABELLED
    xy, true, current = xy[known], true[known], current[known]
    wrong = true != current
    if not wrong.any():
        return None
    best: Lasso | None = None
    for cls, estimate, mask, origin, _ in _areas(xy, true, wrong, np.ones(len(xy), bool), n_classes):
        if best is not None and estimate <= best.gain:
            continue
        polygon = _outline(mask, origin)
        if polygon is None:
            continue
        gain = _gain(GroundRegion(polygon, cls).contains(xy), true, current, cls)
        if best is None or gain > best.gain:
            best = Lasso(polygon, cls, gain)
    return best


def plan_prism(world: np.ndarray, true: np.ndarray, current: np.ndarray, objects: int, n_classes: int,
               cells: tuple[float, ...] = PRISM_CELLS, vertices: int = PRISM_VERTICES) -> Lasso | None:
    """The best region with a height range over these seen points ((N, 3) world; true and
    current class per point, UNLABELLED where unknown): around a connected area of cells whose
    points that are not ground are mostly of one object class (`objects`: the first classes), on
    a grid of each of `PRISM_CELLS` (a person zooms in to trace a fence along a hedge), up to the
    highest of that class's points there (99th percentile), from the bottom of the `BOTTOMS`
    percentiles of their heights that keeps the most ground out, as a person lifts a prism over a
    hedge or a fence above the lawn it stands on. A ground point inside counts against it
    whatever its class now: the prism takes it from the ground layer's lassos. `cells` and
    `vertices` ask more of the operator (finer grids, longer outlines) when measuring what prisms
    can reach at all."""
    known = true != UNLABELLED
    world, true, current = world[known], true[known], current[known]
    wrong = (true != current) & (true < objects)
    if not wrong.any():
        return None
    best: Lasso | None = None
    for size in cells:
        for cls, estimate, mask, origin, in_area in _areas(world[:, :2], true, wrong, true < objects, n_classes, size):
            if best is not None and estimate <= best.gain:
                continue
            polygon = _outline(mask, origin, vertices, size)
            if polygon is not None:
                best = _lift(world, true, current, objects, Lasso(polygon, cls, 0), in_area, best)
    return best


def _lift(world: np.ndarray, true: np.ndarray, current: np.ndarray, objects: int, lasso: Lasso,
          in_area: np.ndarray, best: Lasso | None) -> Lasso | None:
    """`lasso`'s polygon with the height range (`plan_prism`) that puts the most right, if that beats `best`."""
    z = world[in_area & (true == lasso.class_), 2]
    high = float(np.percentile(z, TOP_PERCENTILE))
    for low in (float(v) for v in np.percentile(z, BOTTOMS)):
        inside = GroundRegion(lasso.polygon, lasso.class_, (low, high)).labels(world, None)
        ground = inside & (true >= objects)
        gain = _gain(inside & ~ground, true, current, lasso.class_) - int(ground.sum())
        if best is None or gain > best.gain:
            best = Lasso(lasso.polygon, lasso.class_, gain, (low, high))
    return best
