"""Ground regions on the viewer's side: where a click meets the ground, which points a stored
region labels, and their colours. No GUI here (annotator_ui/ground_panel.py draws and posts).

The service's rule (app/services/point_labels.py, pipeline.propagation.region_labels): a region
gives its class to the ground points inside its polygon (world x, y) in every frame, where
"ground" is the frame's ground estimate plus the points of tracks that are no object (discarded,
or predicted `no_object`) in their kept frames, and never to a point of a track decided with a
class (accepted with a label) in its kept frames; a region with heights gives it to every point
inside its prism (world z between them), a decided track's too; a region of one frame labels only
that frame's points, and a lasso drawn in a frame's view every point of the frame inside it; the
newest region wins where regions overlap.
The viewer paints exactly those points, with the rule the service uses
(`pipeline.propagation.GroundRegion.labels`). In the *track* colour mode the viewer does not
read the tracks' states, and the points of a track keep the track's hue there: that mode shows
tracks, not classes.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from annotator_ui.client import ApiClient
from annotator_ui.geometry import pick_point
from pipeline.assist import NO_OBJECT
from pipeline.propagation import GroundRegion, to_world

NEAR_GROUND_M = 2.0  # ground points within this distance (x, y) of the spot clicked set its height
MIN_NEAR_GROUND = 5  # fewer ground points than this near the click: the frame's median height
MAX_CLICK_RANGE_M = 200.0  # a click ray that meets the ground farther than this picks nothing
MAP_CELL_M = 0.25  # the top view of every frame's ground keeps one point per cell of this side


@dataclass(frozen=True)
class RegionClasses:
    """The classes a region can take: every point class of the sequence's label set, its ground
    classes first (what a lasso mostly labels), with their RGB colours ((3,) uint8 each)."""

    names: tuple[str, ...]
    colours: Mapping[str, np.ndarray]

    @classmethod
    def from_label_set(cls, classes: Sequence[Mapping[str, Any]]) -> RegionClasses:
        """From label-set class rows (`name`, `colour`, `ground`), as the service and the presets give them."""
        rows = sorted(classes, key=lambda c: not c.get("ground", False))  # stable: index order within each
        return cls(tuple(str(c["name"]) for c in rows), {str(c["name"]): np.array(c["colour"], np.uint8) for c in rows})

    @classmethod
    def of(cls, api: ApiClient, sequence_id: int) -> RegionClasses:
        """The sequence's classes, as the service serves them (`GET /sequences/{id}/label-set`): the
        table it checks a region's class against."""
        return cls.from_label_set(api.label_set(sequence_id)["classes"])


@dataclass(frozen=True)
class GroundView:
    """What the lasso needs of the frame shown: points (N, 3) float32 lidar frame, ground (N,)
    bool, T_world_lidar (4, 4), the frame's sequence and its index there."""

    points: np.ndarray
    ground: np.ndarray
    T_world_lidar: np.ndarray
    sequence_id: int
    frame_index: int | None = None


@dataclass(frozen=True)
class StoredRegion:
    """A region as the service holds it: polygon (K, 2) float64 world x, y (not closed), heights
    (world z low, high) or None for a region of ground points; frame_index: the one frame it
    labels (None: all); view: (4, 4) clip_from_world of a lasso drawn in that frame's view, whose
    polygon is then in the camera's device coordinates."""

    id: int
    class_name: str
    polygon: np.ndarray
    heights: tuple[float, float] | None = None
    frame_index: int | None = None
    view: np.ndarray | None = None

    @classmethod
    def from_public(cls, body: Mapping[str, Any]) -> StoredRegion:
        polygon = np.asarray(body["polygon"], np.float64).reshape(-1, 2)
        low, high = body.get("z_min"), body.get("z_max")
        heights = None if low is None or high is None else (float(low), float(high))
        frame, view = body.get("frame_index"), body.get("clip_from_world")
        return cls(int(body["id"]), str(body["class_name"]), polygon, heights,
                   None if frame is None else int(frame), None if view is None else np.asarray(view, np.float64).reshape(4, 4))

    def rule(self) -> GroundRegion:
        """The service's rule for this region (its class left out: the caller colours by index)."""
        return GroundRegion(self.polygon, 0, self.heights, frame=self.frame_index, view=self.view)


def ground_height(points: np.ndarray, ground: np.ndarray, xy: np.ndarray | None = None) -> float | None:
    """Height (lidar z) of the ground at `xy` (lidar x, y): the median z of the frame's ground
    points within NEAR_GROUND_M of it (of all of them when `xy` is None or too few are near).
    None when the frame has no ground point. points (N, 3), ground (N,) bool.

    The median of the ground points, not the sensor height below the pose: the ground points are
    what a region labels, a road slopes and the sensor tilts, and the median ignores the few
    points the ground estimate got wrong (a kerb, a low bush)."""
    pts = points[np.asarray(ground, bool)]
    if not len(pts):
        return None
    if xy is not None:
        near = np.sum((pts[:, :2] - np.asarray(xy, np.float64)) ** 2, axis=1) <= NEAR_GROUND_M**2
        if int(near.sum()) >= MIN_NEAR_GROUND:
            return float(np.median(pts[near, 2]))
    return float(np.median(pts[:, 2]))


def _meet(origin: np.ndarray, direction: np.ndarray, z: float) -> np.ndarray | None:
    """Where the ray meets the plane at height z (None: parallel, behind, or too far)."""
    if abs(direction[2]) < 1e-9:
        return None
    t = (z - origin[2]) / direction[2]
    hit = origin + t * direction
    if t <= 0 or np.linalg.norm(hit[:2] - origin[:2]) > MAX_CLICK_RANGE_M:
        return None
    return hit


def click_on_ground(points: np.ndarray, ground: np.ndarray, origin: np.ndarray, direction: np.ndarray) -> np.ndarray | None:
    """(3,) lidar point where a click ray meets the ground under the frame, or None (the frame has
    no ground, or the ray does not come down to it). The spot aimed at is the ground point the ray
    passes nearest (`pick_point`: what the operator sees under the cursor), else, between sparse
    returns, where the ray meets the frame's median ground height; the ground points around that
    spot give the height the vertex takes, so a vertex on a ramp or a kerb's far side sits on it."""
    o = np.asarray(origin, np.float64).reshape(3)
    d = np.asarray(direction, np.float64).reshape(3)
    z = ground_height(points, ground)
    if z is None or not np.isfinite(d).all() or np.linalg.norm(d) == 0:
        return None
    i = pick_point(points, o, d, candidates=np.asarray(ground, bool))
    if i >= 0:
        spot = np.asarray(points[i, :2], np.float64)
    else:
        first = _meet(o, d, z)
        if first is None:
            return None
        spot = first[:2]
    local = ground_height(points, ground, spot)
    return _meet(o, d, z if local is None else local)


def labelable(ground: np.ndarray, track: np.ndarray, tracks: Mapping[int, Mapping[str, Any]] | None,
              frame_index: int | None) -> np.ndarray:
    """(N,) bool: the points a region may colour (the module docstring's rule). `tracks` maps a
    track id to its TrackPublic (None: the track mode, where points of a track keep its hue)."""
    ground = np.asarray(ground, bool)
    track = np.asarray(track, np.int64)
    if tracks is None:
        return ground & (track == 0)

    def kept(t: Mapping[str, Any]) -> bool:
        return frame_index is None or int(t.get("keep_start", frame_index)) <= frame_index <= int(t.get("keep_end", frame_index))

    decided = [i for i, t in tracks.items() if t.get("status") == "accepted" and t.get("label") and kept(t)]
    no_object = [i for i, t in tracks.items()
                 if (t.get("status") == "discarded" or t.get("predicted_class") == NO_OBJECT) and kept(t)]
    return (ground | np.isin(track, no_object)) & ~np.isin(track, decided)


def region_classes_of_points(points_world: np.ndarray, eligible: np.ndarray, regions: Sequence[StoredRegion],
                             any_eligible: np.ndarray | None = None, frame_index: int | None = None) -> np.ndarray:
    """(N,) int: per point ((N, 3) world, of frame `frame_index`; None: of no one frame, as the
    map of every frame's ground) the index into `regions` of the newest region that labels it,
    -1 = none. `eligible`: the points a region of ground points may label (`labelable`);
    `any_eligible`: those a prism or a view's lasso may (None: every point)."""
    world = np.asarray(points_world, np.float64)
    free = np.asarray(eligible, bool)
    anywhere = np.ones(len(world), bool) if any_eligible is None else np.asarray(any_eligible, bool)
    out = np.full(len(world), -1, np.int64)
    for k, r in enumerate(regions):  # oldest first: a newer region overwrites an older one
        rule = r.rule()
        mine = rule.labels(world, free, frame_index)
        out[mine & anywhere if rule.every_point else mine] = k
    return out


def paint_regions(colours: np.ndarray, points_world: np.ndarray, eligible: np.ndarray,
                  regions: Sequence[StoredRegion], classes: RegionClasses,
                  shade: Any = None, any_eligible: np.ndarray | None = None,
                  frame_index: int | None = None) -> np.ndarray:
    """(N, 3) uint8 colours with the points ((N, 3) world) that regions label in their class
    colours (`region_classes_of_points`; `shade` maps (M, 3) colours to those the cloud shows,
    e.g. its fade). `colours` itself when no point changes (the scene then sends nothing new)."""
    if not regions:
        return colours
    which = region_classes_of_points(points_world, eligible, regions, any_eligible, frame_index)
    hit = which >= 0
    if not hit.any():
        return colours
    grey = np.array([128, 128, 128], np.uint8)  # a class the table does not know (another label set)
    lut = np.stack([classes.colours.get(r.class_name, grey) for r in regions])
    new = lut[which[hit]]
    out = colours.copy()
    out[hit] = new if shade is None else shade(new)
    return out


def ground_map(frames: Iterable[tuple[np.ndarray, np.ndarray, np.ndarray]], cell: float = MAP_CELL_M) -> np.ndarray:
    """(M, 3) float64 world points: the ground estimate of every frame, one point per `cell` x
    `cell` column of the top view (the first seen), so a route's ground fits one cloud. frames:
    ((N, 3) lidar points, (N,) bool ground, (4, 4) T_world_lidar) each."""
    parts = [to_world(np.asarray(points)[np.asarray(ground, bool)], T) for points, ground, T in frames]
    world = np.concatenate(parts) if parts else np.zeros((0, 3))
    if not len(world):
        return world
    ij = np.floor(world[:, :2] / cell).astype(np.int64)
    ij -= ij.min(axis=0)
    _, first = np.unique(ij[:, 0] * (int(ij[:, 1].max()) + 1) + ij[:, 1], return_index=True)  # 1-D keys: fast
    return world[np.sort(first)]
