"""The simulated operator's lasso in one frame's view: the last points no prism separates.

A person looks at one frame from where the sensor stood, each return one dot, turns the camera to
where the dots of one colour should be another (fence boards between the leaves of a hedge, low
leaves among the lawn) and drags a polygon around them; the service labels every point of that
frame inside it, between the camera's near and far planes (`pipeline.propagation.GroundRegion`
with `frame` and `view`). The simulated operator knows the true class of the points it sees and
draws, frame by frame, the lasso that puts the most of them right: around a connected area of
cells of its view (about one beam by one column each) whose points within one span of depths are
mostly of one class, traced along its outline, its depth from the nearest to the farthest point
of that class inside (a person sets the near and far planes around the boards, and the house
seen through their gaps stays out).
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

import cv2
import numpy as np

from bench.effort.ground import MAX_VERTICES, _gain, _outline, class_grid, components
from pipeline.classes import UNLABELLED
from pipeline.propagation import GroundRegion
from pipeline.regions import with_depth_planes

YAWS = 8  # cameras around the sensor, 45 degrees apart
HALF_WIDTH = np.tan(np.deg2rad(25.0))  # horizontal half field of view (tan): neighbours overlap
CELLS = ((0.2, 0.4), (0.6, 1.2))  # degrees (azimuth, elevation) of a view cell: a column and a beam, and 3 x 3 of them
DEPTH_MARGIN = 0.3  # m before the nearest and behind the farthest point of the class in the lasso
# spans of depth an area is read from: two consecutive steps of 1.4x each, so every depth lies in two
DEPTH_EDGES = 1.0 * 1.4 ** np.arange(16)


@dataclass(frozen=True)
class ViewLasso:
    polygon: np.ndarray  # (K, 2) device coordinates of `view`
    view: np.ndarray  # (4, 4) clip_from_world
    class_: int
    gain: int  # points of the frame it puts right minus points it puts wrong

    def rule(self, frame: int) -> GroundRegion:
        return GroundRegion(self.polygon, self.class_, frame=frame, view=self.view)


def camera(T_world_lidar: np.ndarray, yaw: float, elevations: tuple[float, float]) -> np.ndarray:
    """(4, 4) clip_from_world of a camera at the sensor looking along `yaw` (rad, in the lidar's
    x-y plane), its view spanning `elevations` (tan of the lowest and highest), its near and far
    planes at 0.1 and 1000 m."""
    R, o = T_world_lidar[:3, :3], T_world_lidar[:3, 3]
    fwd = R @ np.array([np.cos(yaw), np.sin(yaw), 0.0])
    right = R @ np.array([np.sin(yaw), -np.cos(yaw), 0.0])
    up = R @ np.array([0.0, 0.0, 1.0])
    mid, half = (elevations[0] + elevations[1]) / 2, _half_height(elevations)
    m = np.zeros((4, 4))
    for i, r in enumerate((right / HALF_WIDTH, (up - mid * fwd) / half, fwd, fwd)):
        m[i, :3], m[i, 3] = r, -r @ o
    return with_depth_planes(m, 0.1, 1000.0)


def _half_height(elevations: tuple[float, float]) -> float:
    """Half the view's height (tan): a point off the view's axis is seen 1 / cos(yaw off) higher,
    at the field's edge 10 % more than on the axis."""
    return 1.1 * (elevations[1] - elevations[0]) / 2


def _ndc(view: np.ndarray, world: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Device x, y of (N, 3) world points, their depth, and whether they lie in the view's field."""
    clip = np.concatenate([world, np.ones((len(world), 1))], axis=1) @ view.T
    depth = clip[:, 3]
    front = depth > 1e-6
    xy = clip[:, :2] / np.where(front, depth, 1.0)[:, None]
    return xy, depth, front & np.all(np.abs(xy) <= 1.0, axis=1)


def plan_view_lasso(world: np.ndarray, true: np.ndarray, current: np.ndarray, T_world_lidar: np.ndarray,
                    frame: int, n_classes: int, vertices: int = MAX_VERTICES) -> ViewLasso | None:
    """The best lasso in this frame's views over its (N, 3) world points (true and current class
    per point, UNLABELLED where unknown), or None when nothing it sees is wrong."""
    known = true != UNLABELLED
    wrong = known & (true != current)
    if not wrong.any():
        return None
    lidar = (world - T_world_lidar[:3, 3]) @ T_world_lidar[:3, :3]
    tan_el = lidar[:, 2] / np.maximum(np.hypot(lidar[:, 0], lidar[:, 1]), 1e-6)
    elevations = (float(tan_el.min()) - 0.01, float(tan_el.max()) + 0.01)
    azimuth = np.arctan2(lidar[:, 1], lidar[:, 0])
    best: ViewLasso | None = None
    for k in range(YAWS):
        yaw = 2 * np.pi * k / YAWS
        if not (wrong & (np.abs(np.angle(np.exp(1j * (azimuth - yaw)))) < np.arctan(HALF_WIDTH))).any():
            continue
        view = camera(T_world_lidar, yaw, elevations)
        xy, depth, seen = _ndc(view, world)
        for cell in CELLS:
            best = _best_in_view(world, true, current, frame, n_classes, vertices, view, xy, depth, seen & known,
                                 wrong & seen, cell, elevations, best)
    return best


def _best_in_view(world, true, current, frame, n_classes, vertices, view, xy, depth, seen, wrong, cell, elevations,
                  best):
    """`best`, or a better lasso around an area of this view's cells (`plan_view_lasso`)."""
    scale = np.array([np.tan(np.deg2rad(cell[0])) / HALF_WIDTH, np.tan(np.deg2rad(cell[1])) / _half_height(elevations)])
    idx = np.flatnonzero(seen)
    if not wrong[idx].any():
        return best
    pseudo = xy[idx] / scale  # one unit: one view cell
    for lo_d, hi_d in zip(DEPTH_EDGES[:-2], DEPTH_EDGES[2:], strict=True):
        span = (depth[idx] >= lo_d) & (depth[idx] < hi_d)
        if (wrong[idx] & span).any():
            best = _best_in_span(world, true, current, frame, n_classes, vertices, view, xy, depth, idx, pseudo,
                                 wrong[idx] & span, span, scale, best)
    return best


def _best_in_span(world, true, current, frame, n_classes, vertices, view, xy, depth, idx, pseudo, wrong, span,
                  scale, best):
    """`best`, or a better lasso around an area of the view's cells whose points in `span` (a
    span of depths) are mostly of one class."""
    for cls, estimate, mask, origin, in_area in _areas_in_span(pseudo, true[idx], wrong, span, n_classes):
        if best is not None and estimate <= best.gain:
            continue
        outline = _outline(mask, origin, vertices, 1.0)
        if outline is None:
            continue
        d = depth[idx][in_area & span & (true[idx] == cls)]
        near, far = max(float(d.min()) - DEPTH_MARGIN, 0.05), float(d.max()) + DEPTH_MARGIN
        lasso = ViewLasso(outline * scale, with_depth_planes(view, near, far), cls, 0)
        lo, hi = lasso.polygon.min(0), lasso.polygon.max(0)
        near_box = np.flatnonzero(np.all((xy >= lo) & (xy <= hi), axis=1))
        inside = np.zeros(len(world), bool)
        inside[near_box] = lasso.rule(frame).labels(world[near_box], None, frame)
        gain = _gain(inside, true, current, cls)
        if best is None or gain > best.gain:
            best = ViewLasso(lasso.polygon, lasso.view, cls, gain)
    return best


def _areas_in_span(xy: np.ndarray, true: np.ndarray, wrong: np.ndarray, span: np.ndarray,
                   n_classes: int) -> Iterator[tuple[int, int, np.ndarray, np.ndarray, np.ndarray]]:
    """`bench.effort.ground._areas` over unit cells, the majority read from the `span` points, and
    a cell with none of them (a gap between boards, where the house behind shows) joining the
    area of a neighbour in its row: the lasso spans it, its planes keep what is behind out."""
    origin, cell, counts = class_grid(xy, true, span, n_classes, 1.0)
    major, empty = counts.argmax(2), counts.sum(2) == 0
    for cls in np.unique(true[wrong]):
        core = ((major == cls) & ~empty).astype(np.uint8)
        # along a beam's row only (axis 0 is the view's x): across rows it would join two rows of
        # boards over the leaves between them, whose outline holds the leaves
        mask = core | (empty & (cv2.dilate(core, np.ones((3, 1), np.uint8)) > 0)).astype(np.uint8)
        for estimate, comp, in_area in components(mask, cell, wrong & (true == cls)):
            yield int(cls), estimate, comp, origin, in_area
