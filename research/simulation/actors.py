"""Things that move: cars, cyclists and pedestrians, each on a path, posed at time t.

Two kinds of path:
  * `LanePath` follows the route at arc length s0 + v t with a lateral offset; overtaking cars
    swing into the other lane while they pass the ego vehicle, and pedestrians follow the
    sidewalk (which steps out behind parking bays);
  * `PolylinePath` walks a polyline back and forth (along a façade or a hedge, across the
    road at a zebra crossing).
An actor's primitives at time t come from its model (`models.py`) posed on the ground.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from research.simulation.furniture import add_cargo_box, add_scooter
from research.simulation.ground import GroundModel
from research.simulation.models import (
    CarShape,
    PersonShape,
    add_bicycle,
    add_car,
    add_person,
    add_rider,
)
from research.simulation.route import SAMPLE_STEP, EgoProfile, Route
from research.simulation.shapes import Material, PrimitiveBuilder, PrimitiveSet, rot_z


@dataclass(frozen=True)
class LanePath:
    """Arc length s(t) = s0 + v t along the route at lateral offset `lat` (+ = left).

    follow: (M,) float32 per-sample offset added to `lat` (sidewalks behind bays), or None.
    overtake_lat: lateral offset used while within `overtake_gap` m of the ego, or None.
    """

    route: Route
    s0: float
    v: float
    lat: float
    follow: np.ndarray | None = None
    ego: EgoProfile | None = None
    overtake_lat: float | None = None
    overtake_gap: float = 14.0

    def _lat(self, s: np.ndarray, t: float) -> np.ndarray:
        lat = np.full(np.shape(s), self.lat)
        if self.follow is not None:
            lat = lat + np.sign(self.lat) * self.follow[self.route.index(s)]
        if self.overtake_lat is not None and self.ego is not None:
            gap = (
                np.mod(s - self.ego.s_at(t) + self.route.length / 2, self.route.length)
                - self.route.length / 2
            )
            # Smooth lane change over 8 m on both sides of the passing window.
            w = np.clip((self.overtake_gap + 8.0 - np.abs(gap)) / 8.0, 0.0, 1.0)
            w = 0.5 - 0.5 * np.cos(np.pi * w)
            lat = lat * (1 - w) + self.overtake_lat * w
        return lat

    def pose(self, t: float) -> tuple[np.ndarray, float]:
        """((2,) scene xy, yaw) at time t."""
        s = self.s0 + self.v * t
        ds = 0.5 if self.v >= 0 else -0.5
        ss = np.array([s, s + ds])
        lat = self._lat(ss, t)
        p = self.route.offset(ss, lat)
        d = p[1] - p[0]
        return p[0], float(np.arctan2(d[1], d[0]))


@dataclass(frozen=True)
class PolylinePath:
    """Back and forth along `points` (K, 2) at speed v, at distance v (t - t0) from the start."""

    points: np.ndarray
    v: float
    t0: float = 0.0
    cum: np.ndarray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        seg = np.linalg.norm(np.diff(self.points, axis=0), axis=1)
        object.__setattr__(self, "cum", np.concatenate([[0.0], np.cumsum(seg)]))

    def pose(self, t: float) -> tuple[np.ndarray, float]:
        total = self.cum[-1]
        d = np.mod(self.v * (t - self.t0), 2 * total)
        backwards = d > total
        if backwards:
            d = 2 * total - d
        i = int(np.clip(np.searchsorted(self.cum, d, side="right") - 1, 0, len(self.points) - 2))
        f = (d - self.cum[i]) / max(self.cum[i + 1] - self.cum[i], 1e-9)
        p = self.points[i] * (1 - f) + self.points[i + 1] * f
        seg = self.points[i + 1] - self.points[i]
        yaw = float(np.arctan2(seg[1], seg[0])) + (np.pi if backwards else 0.0)
        return p, yaw


Path = LanePath | PolylinePath


@dataclass(frozen=True)
class Actor:
    """A moving (or standing) car, cyclist or person.

    kind: "car" | "cyclist" | "person"; semantic: SemanticKITTI id written for its points.
    speed: m/s along the path (animation rate); phase: gait or crank phase offset (rad).
    """

    instance: int
    kind: str
    semantic: int
    path: Path
    shape: CarShape | PersonShape
    speed: float
    phase: float = 0.0
    frame_refl: float = 0.4
    model: PrimitiveSet | None = None  # rigid actors (cars): primitives in the object frame
    vehicle: str = "bike"  # cyclists: bike | child (a child on a small bike) | cargo | scooter
    # people walking together as one object: (shape, dx, dy, gait phase) beside the actor
    companions: tuple[tuple[PersonShape, float, float, float], ...] = ()

    def position(self, t: float) -> np.ndarray:
        return self.path.pose(t)[0]

    def primitives(self, t: float, ground: GroundModel) -> PrimitiveSet:
        """The actor's primitives in the scene frame at time t."""
        xy, yaw = self.path.pose(t)
        z = float(ground.height(xy[None])[0])
        n = ground.normal(xy[None])[0]
        return self.posed(t, xy, yaw, z, n)

    def posed(self, t: float, xy: np.ndarray, yaw: float, z: float, normal: np.ndarray) -> PrimitiveSet:
        """The primitives at time t for a pose already computed: ground point (xy, z), heading, slope normal."""
        pos = np.array([xy[0], xy[1], z])
        if self.kind == "car":
            rot = frame_on_slope(normal, yaw)
            if self.model is not None:
                return self.model.transformed(rot, pos)
            b = PrimitiveBuilder()
            add_car(b, self.shape, self.semantic, self.instance)  # type: ignore[arg-type]
            return b.build(rot, pos)
        b = PrimitiveBuilder()
        if self.kind == "cyclist" and self.vehicle == "scooter":
            add_scooter(b, self.shape, self.semantic, self.instance, Material(refl=self.frame_refl, drop=0.02))  # type: ignore[arg-type]
        elif self.kind == "cyclist":
            frame = Material(refl=self.frame_refl, drop=0.02)
            add_bicycle(b, self.semantic, self.instance, frame)
            crank = self.phase + 2 * np.pi * self.speed * t / 5.3  # 5.3 m per crank turn
            add_rider(b, self.shape, self.semantic, self.instance, crank, 0.65)  # type: ignore[arg-type]
            if self.vehicle == "cargo":
                add_cargo_box(b, self.semantic, self.instance, frame)
            elif self.vehicle == "child":
                b.scale(0.7)
        else:
            stride = 0.8 * self.shape.height  # type: ignore[union-attr]  # one full gait cycle
            gait = self.phase + 2 * np.pi * self.speed * t / stride
            swing = 0.42 if self.speed > 0 else 0.0
            add_person(b, self.shape, self.semantic, self.instance, gait, swing)  # type: ignore[arg-type]
            for shape, dx, dy, phase in self.companions:
                c = PrimitiveBuilder()
                stride = 0.8 * shape.height
                add_person(c, shape, self.semantic, self.instance, phase + 2 * np.pi * self.speed * t / stride, swing)
                c.shift(dx, dy)
                b.extend(c)
        return b.build(rot_z(yaw), pos)


def actor_poses(actors: tuple[Actor, ...] | list[Actor], t: float) -> tuple[np.ndarray, np.ndarray]:
    """((A, 2) xy, (A,) yaw) of all actors at time t; lane paths are evaluated together."""
    xy = np.zeros((len(actors), 2))
    yaw = np.zeros(len(actors))
    lanes = [i for i, a in enumerate(actors) if isinstance(a.path, LanePath)]
    for i, a in enumerate(actors):
        if not isinstance(a.path, LanePath):
            xy[i], yaw[i] = a.path.pose(t)
    if not lanes:
        return xy, yaw
    paths: list[LanePath] = [actors[i].path for i in lanes]  # type: ignore[misc]
    route = paths[0].route
    v = np.array([p.v for p in paths])
    s = np.array([p.s0 for p in paths]) + v * t
    ss = np.stack([s, s + np.where(v >= 0, 0.5, -0.5)], axis=1)  # (L, 2)
    lat0 = np.array([p.lat for p in paths])
    lat = np.repeat(lat0[:, None], 2, axis=1)
    follows: dict[int, np.ndarray] = {id(p.follow): p.follow for p in paths if p.follow is not None}
    for key, arr in follows.items():
        m = np.array([p.follow is not None and id(p.follow) == key for p in paths])
        lat[m] += np.sign(lat0[m])[:, None] * arr[route.index(ss[m])]
    over = np.array([p.overtake_lat is not None and p.ego is not None for p in paths])
    if over.any():
        ego = next(p.ego for p in paths if p.ego is not None)
        gap = np.mod(ss[over] - ego.s_at(t) + route.length / 2, route.length) - route.length / 2
        gaps = np.array([p.overtake_gap for p, o in zip(paths, over, strict=True) if o])[:, None]
        w = np.clip((gaps + 8.0 - np.abs(gap)) / 8.0, 0.0, 1.0)
        w = 0.5 - 0.5 * np.cos(np.pi * w)
        target = np.array([p.overtake_lat for p, o in zip(paths, over, strict=True) if o])[:, None]
        lat[over] = lat[over] * (1 - w) + target * w
    pts = route.offset(ss, lat)  # (L, 2, 2)
    d = pts[:, 1] - pts[:, 0]
    xy[lanes] = pts[:, 0]
    yaw[lanes] = np.arctan2(d[:, 1], d[:, 0])
    return xy, yaw


def frame_on_slope(normal: np.ndarray, yaw: float) -> np.ndarray:
    """(3, 3) rotation of a vehicle heading `yaw` standing on ground of unit `normal` (3,)."""
    n = normal
    fwd = np.array([np.cos(yaw), np.sin(yaw), 0.0])
    x = fwd - (fwd @ n) * n
    x /= np.linalg.norm(x)
    y = np.array([n[1] * x[2] - n[2] * x[1], n[2] * x[0] - n[0] * x[2], n[0] * x[1] - n[1] * x[0]])
    return np.stack([x, y, n], axis=1)


def ground_frame(ground: GroundModel, xy: np.ndarray, yaw: float) -> np.ndarray:
    """(3, 3) rotation of a vehicle at `xy` heading `yaw`, standing on the ground's slope."""
    return frame_on_slope(ground.normal(np.asarray(xy, float)[None])[0], yaw)


def lane_offsets_smoothed(values: np.ndarray, window_m: float = 8.0) -> np.ndarray:
    """(M,) circular moving average of per-sample offsets over `window_m` metres."""
    k = max(1, int(window_m / SAMPLE_STEP))
    padded = np.concatenate([values[-k:], values, values[:k]])
    kernel = np.ones(2 * k + 1) / (2 * k + 1)
    return np.convolve(padded, kernel, mode="same")[k:-k].astype(np.float32)
