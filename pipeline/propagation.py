"""A label for every point: where each point's class comes from, and the labels of points no
review of their own reached.

A point's class comes, in this order, from

1. its track's decision (`reviewed`, or `bulk` for a bulk-accepted prediction) in the track's
   kept frames;
2. an operator's region (`region`), in any frame: a polygon on the top view gives its class to the
   ground points inside it (the ground estimate's, or points of a track that is no object) that
   no decided track holds; one with a height range gives it to every point inside the prism,
   a decided track's too (the operator painted them: a fence grown into a reviewed hedge). A
   region of one frame holds only that frame's points; a lasso drawn in a frame's view gives its
   class to every point of the frame that it holds, whatever else holds them (the last points no
   track, prism or radius separates: fence boards inside a hedge, low leaves among the lawn);
3. the nearest point so decided within `radius` in the world frame, in this frame or a nearby one
   (`propagated`): points of segments too small to be samples, points the range image did not
   give a segment (deeper returns through foliage), parts of tracks nobody reviewed. A point the
   ground estimate took reaches only `ground_radius`, so a road beside a reviewed wall stays road;
   then, for points that are not ground, the nearest point of its own frame that a region without
   heights gave an object class, within `region_radius` (`propagated`): the ground estimate took
   the low leaves of a bush the operator lassoed, and the rest of the bush stands just above them;
4. its track's predicted class (`predicted`), else, for a point the ground estimate did not take,
   the nearest point of its own frame labelled so far within `far_radius` (`predicted`, or
   `propagated` when that point's class was decided). This step never reaches a point the ground
   estimate took: on kitti_seq00 after 200 operator actions, 9,259 of the 9,997 such points it
   reached within `ground_radius` were ground (without a world search, the frame's own decided
   points reach them within `ground_radius` here instead);
5. the ground class, for ground points, when asked for (`ground`).

A point none of these reaches keeps no class (`none`), and is counted. Distances are metres.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from pipeline.regions import ScreenLasso, points_in_polygon

NONE = 255  # class index of a point without a class
SOURCES: tuple[str, ...] = ("none", "reviewed", "bulk", "propagated", "predicted", "ground", "region")
SOURCE = {name: i for i, name in enumerate(SOURCES)}
DECIDED = (SOURCE["reviewed"], SOURCE["bulk"])


@dataclass(frozen=True)
class Rules:
    """How far labels travel. radius: from decided points to a point that is not ground (m);
    ground_radius: to a point the ground estimate took (m); far_radius: within its own frame, to a
    point that is not ground and that nothing reached before (m; isolated returns and foliage
    without a segment of its own); voxel: decided points are thinned to one per voxel (m) before
    they are searched. 0 turns a step off. Chosen on the three shared real clips together by the
    operator benchmark (docs/effort.md): 1.0 m labelled more non-ground points right than 0.5 m
    and 0.3 m on each; 0.2 m into ground points gains about as much non-ground as it costs
    ground against 0.1 m and keeps ground above 94 % on each; a far radius of 10 m labelled more
    non-ground points right than 5 m, 2 m and none on each (20 m: the same), and touches no
    ground point. region_radius: from the points that a region without heights gave an object
    class to points of the same frame that are not ground and that no decided point reached (m);
    0.3 m labelled at least as many non-ground points right as none on each clip, after 50 actions
    and after 150 (+1.25 points on kitti_seq02 after 54), and more than 0.5 m and 1 m in the mean.
    From the points of a region with heights it labelled fewer on one clip: an operator leaves out
    of a prism what is not its class (docs/effort.md)."""

    radius: float = 1.0
    ground_radius: float = 0.2
    far_radius: float = 10.0
    region_radius: float = 0.3
    voxel: float = 0.05


@dataclass(frozen=True)
class GroundRegion:
    """A polygon an operator drew on the top view (world x, y; (K, 2), K >= 3) and its class.
    Without `heights` the ground points inside it take the class in every frame; with heights
    (world z low, high) every point inside the prism does. With `frame` only that frame's points
    count. With `view` (the (4, 4) clip_from_world of the camera it was drawn with; `frame` too)
    the polygon is in its normalised device coordinates and every point of the frame that the
    lasso holds (`pipeline.regions.ScreenLasso`, within `heights` if given) takes the class. A
    later region is drawn over an earlier one where they overlap. object_: whether the class is
    an object class (not ground)."""

    polygon: np.ndarray
    class_: int
    heights: tuple[float, float] | None = None
    object_: bool = False
    frame: int | None = None
    view: np.ndarray | None = None

    @property
    def every_point(self) -> bool:
        """Whether it labels every point it holds (a prism or a view's lasso), not only free ground."""
        return self.heights is not None or self.view is not None

    def contains(self, xy: np.ndarray) -> np.ndarray:
        """(N,) bool of (N, 2) world points; the bounding box first, so a frame far from the
        polygon costs one comparison per point."""
        lo, hi = self.polygon.min(0), self.polygon.max(0)
        near = np.flatnonzero(np.all((xy >= lo) & (xy <= hi), axis=1))
        out = np.zeros(len(xy), bool)
        out[near] = points_in_polygon(xy[near], self.polygon)
        return out

    def labels(self, world: np.ndarray, free_ground: np.ndarray | None,
               frame: int | np.ndarray | None = None) -> np.ndarray:
        """(N,) bool the points of (N, 3) world points this region labels: inside its prism or
        its view's lasso, or without either the `free_ground` points inside its polygon (None: no
        point is free). frame: the points' frame index (an int, or (N,) ints); a region of one
        frame labels nothing of points whose frame is not given."""
        if self.frame is not None and (frame is None or (np.ndim(frame) == 0 and frame != self.frame)):
            return np.zeros(len(world), bool)  # another frame's: an operator may draw hundreds
        if self.every_point:
            keep = np.ones(len(world), bool)
            if self.heights is not None:
                keep = (world[:, 2] >= self.heights[0]) & (world[:, 2] <= self.heights[1])
        else:
            keep = np.asarray(free_ground, bool) if free_ground is not None else np.zeros(len(world), bool)
        if self.frame is not None:
            keep = keep & (np.broadcast_to(-1 if frame is None else frame, len(world)) == self.frame)
        idx = np.flatnonzero(keep)
        out = np.zeros(len(world), bool)
        if self.view is not None:
            out[idx[ScreenLasso(self.polygon, self.view).contains(world[idx])]] = True
        else:
            out[idx[self.contains(world[idx, :2])]] = True
        return out


@dataclass(frozen=True)
class PointLabels:
    """Per point: class_ (N,) uint8 class index (NONE = none), source (N,) uint8 (SOURCES),
    confidence (N,) float32 in [0, 1] (0 without a class)."""

    class_: np.ndarray
    source: np.ndarray
    confidence: np.ndarray

    @classmethod
    def empty(cls, n: int) -> PointLabels:
        return cls(np.full(n, NONE, np.uint8), np.zeros(n, np.uint8), np.zeros(n, np.float32))

    def set(self, mask: np.ndarray, class_: np.ndarray, source: np.ndarray | int, confidence: np.ndarray) -> None:
        """Give the points of `mask` these values (arrays of mask.sum() values, or scalars)."""
        self.class_[mask], self.source[mask], self.confidence[mask] = class_, source, confidence

    @property
    def labelled(self) -> np.ndarray:
        return self.class_ != NONE


@dataclass(frozen=True)
class TrackClasses:
    """Classes of whole tracks in one frame: ids (T,) int64 ascending track ids, class_ (T,) uint8,
    source (T,) uint8, confidence (T,) float32."""

    ids: np.ndarray
    class_: np.ndarray
    source: np.ndarray
    confidence: np.ndarray

    def __post_init__(self) -> None:
        assert np.all(np.diff(self.ids) > 0), "track ids must ascend"
        assert len(self.class_) == len(self.source) == len(self.confidence) == len(self.ids)

    @classmethod
    def of(cls, rows: list[tuple[int, int, int, float]]) -> TrackClasses:
        """From (track id, class, source, confidence) rows in any order."""
        rows = sorted(rows)
        cols = list(zip(*rows, strict=True)) if rows else [[], [], [], []]
        return cls(np.asarray(cols[0], np.int64), np.asarray(cols[1], np.uint8), np.asarray(cols[2], np.uint8),
                   np.asarray(cols[3], np.float32))

    def lookup(self, track: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(N,) bool whether each point's track is listed, and (N,) its row (valid where listed)."""
        if len(self.ids) == 0:
            return np.zeros(len(track), bool), np.zeros(len(track), np.int64)
        row = np.minimum(np.searchsorted(self.ids, track), len(self.ids) - 1)
        return (self.ids[row] == track) & (track > 0), row


def to_world(points: np.ndarray, T_world_lidar: np.ndarray | None) -> np.ndarray:
    """(N, 3) float64 world coordinates of (N, 3) lidar points (the lidar frame without a pose)."""
    p = np.asarray(points, np.float64)
    if T_world_lidar is None:
        return p
    T = np.asarray(T_world_lidar, np.float64)
    return p @ T[:3, :3].T + T[:3, 3]


def thin(points: np.ndarray, labels: PointLabels, voxel: float) -> tuple[np.ndarray, PointLabels]:
    """The labelled points, one per voxel of side `voxel` (the first), with their labels."""
    keep = np.flatnonzero(labels.labelled)
    if voxel > 0 and len(keep):
        cells = np.floor(points[keep] / voxel).astype(np.int64)
        _, first = np.unique(cells, axis=0, return_index=True)
        keep = keep[np.sort(first)]
    return points[keep], PointLabels(labels.class_[keep], labels.source[keep], labels.confidence[keep])


class NearestLabel:
    """The labels of a cloud of points, searched by distance (a k-d tree)."""

    def __init__(self, points: np.ndarray, labels: PointLabels) -> None:
        from scipy.spatial import cKDTree

        self.labels = labels
        self.tree = cKDTree(points) if len(points) else None

    def query(self, points: np.ndarray, radius: float) -> tuple[np.ndarray, np.ndarray]:
        """(M,) bool whether a labelled point lies within `radius` of each query point, and (M,)
        the index of the nearest (valid where found)."""
        if self.tree is None or radius <= 0 or len(points) == 0:
            return np.zeros(len(points), bool), np.zeros(len(points), np.int64)
        dist, idx = self.tree.query(points, k=1, distance_upper_bound=radius, workers=-1)
        found = np.isfinite(dist)
        return found, np.where(found, idx, 0)


def decided_labels(track: np.ndarray, decided: TrackClasses) -> PointLabels:
    """Step 1 alone: the points of decided tracks (the reviewed-only export, and what the world
    search of nearby frames reads)."""
    out = PointLabels.empty(len(track))
    hit, row = decided.lookup(np.asarray(track, np.int64))
    out.set(hit, decided.class_[row[hit]], decided.source[row[hit]], decided.confidence[row[hit]])
    return out


def region_labels(out: PointLabels, ground: np.ndarray, world: np.ndarray, regions: Sequence[GroundRegion],
                  frame: int | None = None) -> np.ndarray:
    """Step 2: each region, oldest first, gives its class to the points of frame `frame` it labels
    (`GroundRegion.labels`; ground points that no decided track holds, or its prism's or view
    lasso's). Returns (N,) bool the points that a region of ground points gave an object class."""
    spreads = np.zeros(len(world), bool)
    if not regions:
        return spreads
    free = np.asarray(ground, bool) & ~out.labelled
    for r in regions:
        mask = r.labels(world, free, frame)
        out.set(mask, r.class_, SOURCE["region"], 1.0)
        spreads[mask] = r.object_ and not r.every_point
    return spreads


def _nearest(world: np.ndarray, out: PointLabels, keep: np.ndarray, voxel: float) -> NearestLabel:
    """The labelled points of `keep`, thinned to one per voxel, searched by distance."""
    return NearestLabel(*thin(world, PointLabels(np.where(keep, out.class_, NONE).astype(np.uint8), out.source,
                                                 out.confidence), voxel))


def _take(out: PointLabels, want: np.ndarray, points: np.ndarray, near: NearestLabel, radius: float,
          source: np.ndarray | int | None = None) -> np.ndarray:
    """Give the points of `want` the label of their nearest point in `near` within `radius`;
    their source is `source`, or else `propagated` from a decided point and `predicted` otherwise.
    Returns (N,) bool the points it labelled."""
    idx = np.flatnonzero(want)
    found, nn = near.query(points[idx], radius)
    idx, nn = idx[found], nn[found]
    if source is None:
        source = np.where(np.isin(near.labels.source[nn], DECIDED), SOURCE["propagated"], SOURCE["predicted"])
    mask = np.zeros(len(want), bool)
    mask[idx] = True
    out.set(mask, near.labels.class_[nn], source, near.labels.confidence[nn])
    return mask


def resolve_frame(track: np.ndarray, ground: np.ndarray, world: np.ndarray, decided: TrackClasses,
                  predicted: TrackClasses, field: NearestLabel | None, rules: Rules,
                  ground_class: int | None, regions: Sequence[GroundRegion] = (), frame: int | None = None) -> PointLabels:
    """Every point's class, source and confidence in one frame (module docstring).

    track: (N,) int64 track id per point (0 = none); ground: (N,) bool the ground estimate;
    world: (N, 3) float64 world coordinates; decided / predicted: the frame's track classes;
    field: decided points of this and nearby frames (None = no world search); ground_class: the
    class written on ground points no other step reached (None = leave them without one);
    regions: the operators' ground regions, oldest first; frame: this frame's index (what a
    region of one frame is matched against).
    """
    track = np.asarray(track, np.int64)
    ground = np.asarray(ground, bool)
    out = decided_labels(track, decided)
    spreads = region_labels(out, ground, world, regions, frame)
    if field is not None:
        _take(out, ~out.labelled & ~ground, world, field, rules.radius, SOURCE["propagated"])
        _take(out, ~out.labelled & ground, world, field, rules.ground_radius, SOURCE["propagated"])
    by_region = out.source == SOURCE["region"]
    if rules.region_radius > 0 and spreads.any():  # step 3's second part: a lassoed object's reach
        by_region |= _take(out, ~out.labelled & ~ground, world, _nearest(world, out, spreads, rules.voxel),
                           rules.region_radius, SOURCE["propagated"])
    hit, row = predicted.lookup(track)
    hit &= ~out.labelled
    out.set(hit, predicted.class_[row[hit]], SOURCE["predicted"], predicted.confidence[row[hit]])
    if (~out.labelled).any() and out.labelled.any():
        # regions label what they hold and, just above a lassoed object, its points; no more:
        # a wall beside a lawn is not lawn
        near = _nearest(world, out, ~by_region, rules.voxel)
        rest = ~out.labelled
        _take(out, rest & ~ground, world, near, max(rules.radius, rules.far_radius))
        if field is None:  # no world search (step 3): this frame's decided points reach the ground here
            decided_near = _nearest(world, out, np.isin(out.source, DECIDED), rules.voxel)
            _take(out, rest & ground, world, decided_near, rules.ground_radius)
    if ground_class is not None:
        out.set(~out.labelled & ground, ground_class, SOURCE["ground"], 1.0)
    return out
