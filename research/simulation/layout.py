"""Static layout of the campus along the loop: what stands where, with instance ids.

Each side of every straight is cut into stretches of 25-65 m, each with a character:

    avenue    a row of street trees in the verge, bushes, a hedge behind
    frontage  buildings close to the sidewalk (people walk along their walls), bike racks
    hedges    hedges lining the sidewalk (people walk along them), trees behind
    bays      parallel parking bays full of parked cars, trees behind the sidewalk
    lot       a parking lot with rows of perpendicular cars, lamps and cones
    open      grass with scattered trees, bushes, benches, bins, fences

Behind them stand more buildings (varied footprints: L-shaped wings, recessed entrances
under an overhang on pillars, towers; fronts with recessed windows), and trees and bushes are
scattered over the grass. Things touch as on real streets (`contacts`): hedges, climbers and
shrubs against walls and fences, shrubs against trunks, cars parked bumper to bumper, people
and bikes leaning on walls, bikes in racks.
Lamps line the sidewalks; signs and bollards mark the zebra crossings. Placement keeps
objects off the road and sidewalks and apart from each other with a 0.5 m occupancy grid.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from pipeline.classes import POINT_CLASSES, to_ours
from research.simulation import contacts as ct
from research.simulation import furniture as fu
from research.simulation import models as m
from research.simulation.actors import ground_frame
from research.simulation.buildings import Buildings, Facade
from research.simulation.ground import GRID_CELL, GroundModel
from research.simulation.route import SAMPLE_STEP, Route
from research.simulation.shapes import Material, PrimitiveBuilder, PrimitiveSet, rot_x, rot_z
from research.simulation.style import STYLES, CampusStyle

TRUNK_SHRUB_P = 0.25  # trees with a shrub grown against the trunk
GARDEN_FENCE_P = 0.5  # hedge stretches with a fence behind the sidewalk (planting against it)
STRETCH_TYPES = ("avenue", "frontage", "hedges", "bays", "lot", "open")
STRETCH_P = (0.2, 0.17, 0.15, 0.26, 0.12, 0.10)
BAY_WIDTH = 2.3
# per tree style, the ranges of (crown radius, crown height, crown base, trunk radius), metres
TREE_SHAPES = {
    "young": ((0.9, 1.6), (1.6, 2.8), (1.6, 2.4), (0.06, 0.11)),
    "conifer": ((1.2, 2.2), (4.0, 8.0), (0.6, 1.6), (0.12, 0.25)),
    "wide": ((3.2, 5.0), (3.5, 6.0), (2.4, 3.6), (0.25, 0.42)),
    "default": ((2.0, 3.4), (3.0, 5.5), (2.0, 3.4), (0.14, 0.3)),
}


@dataclass(frozen=True)
class InstanceInfo:
    """Ground truth of one instance: what it is and whether it moves.

    semantic: SemanticKITTI ids its points carry; position: scene xyz of its base (static ones).
    """

    id: int
    kind: str
    semantic: tuple[int, ...]
    moving: bool
    position: tuple[float, float, float] | None = None
    dark: bool = False

    @property
    def cls(self) -> str:
        """Our class name (pipeline.classes) of the instance."""
        return POINT_CLASSES[int(to_ours(np.asarray(self.semantic[:1]))[0])]


@dataclass
class Stretch:
    side: int  # +1 left of the direction of travel, -1 right
    s0: float
    s1: float
    kind: str


@dataclass
class RoadSpec:
    """Cross-section of the street (metres)."""

    road_half: float
    sidewalk_left: float
    sidewalk_right: float
    curb: float

    @property
    def lane(self) -> float:
        return self.road_half / 2

    def sidewalk(self, side: int) -> float:
        return self.sidewalk_left if side > 0 else self.sidewalk_right


@dataclass
class Registry:
    """Instance ids, handed out in creation order from 1."""

    infos: dict[int, InstanceInfo] = field(default_factory=dict)

    def new(
        self, kind: str, semantic: tuple[int, ...], moving: bool = False, position=None, dark=False
    ) -> int:
        iid = len(self.infos) + 1
        if iid > 0xFFFF:
            raise ValueError("more than 65535 instances in one scene")
        pos = None if position is None else tuple(round(float(v), 3) for v in position)
        self.infos[iid] = InstanceInfo(iid, kind, tuple(int(s) for s in semantic), moving, pos, bool(dark))
        return iid


def plan_stretches(rng: np.random.Generator, route: Route, start_s: float) -> list[Stretch]:
    """Stretches of 25-65 m on both sides of every straight.

    Where the ego vehicle starts (`start_s`), the right side is an avenue (trees, bushes) and
    the left side has parking bays, so that even a short run sees every static class.
    """
    spans = []
    for a, b in route.straight_runs(margin=3.0):
        for side in (1, -1):
            s = a
            while b - s > 15.0:
                length = min(rng.uniform(25.0, 65.0), b - s)
                spans.append((side, s, s + length))
                s += length
    # Kinds from a shuffled deck in the STRETCH_P proportions: every loop gets the same mix.
    counts = np.floor(np.asarray(STRETCH_P) * len(spans)).astype(int)
    deck = [k for k, c in zip(STRETCH_TYPES, counts, strict=True) for _ in range(c)]
    deck += [str(k) for k in rng.choice(STRETCH_TYPES, size=len(spans) - len(deck), p=STRETCH_P)]
    deck = [deck[i] for i in rng.permutation(len(deck))]
    out = []
    for (side, s0, s1), kind in zip(spans, deck, strict=True):
        if kind == "lot" and s1 - s0 < 35.0:
            kind = "bays"
        if np.mod(start_s - s0 + 35.0, route.length) < s1 - s0 + 45.0:  # overlaps [start - 10, start + 35]
            kind = "avenue" if side < 0 else "bays"
        out.append(Stretch(side, s0, s1, kind))
    return out


def low_widths(route: Route, road: RoadSpec, stretches: list[Stretch], rng: np.random.Generator):
    """(left, right) (M,) float32 half widths of the low surface: road plus bays and lots."""
    n = len(route.xy)
    left = np.full(n, road.road_half, np.float32)
    right = np.full(n, road.road_half, np.float32)
    for st in stretches:
        if st.kind not in ("bays", "lot"):
            continue
        extra = BAY_WIDTH if st.kind == "bays" else rng.uniform(18.0, 21.0)
        idx = route.index(np.arange(st.s0 + 4.0, st.s1 - 4.0, SAMPLE_STEP))
        (left if st.side > 0 else right)[idx] = road.road_half + extra
    return left, right


class Layout(Buildings):
    """Places static objects; collects their primitives and instance records."""

    def __init__(
        self, rng: np.random.Generator, route: Route, ground: GroundModel, road: RoadSpec, reg: Registry,
        style: CampusStyle | None = None,
        extra: np.random.Generator | None = None,
    ):
        self.rng = rng
        self.style = style or STYLES["a"]
        # the varied styles' own stream: their extra kinds leave the plain draws (layout) unchanged
        self.extra = extra if self.style.variety else None
        self.route = route
        self.ground = ground
        self.road = road
        self.reg = reg
        self.occupied = np.zeros(ground.lat.shape, bool)
        self.sets: list[PrimitiveSet] = []
        self.facades: list[Facade] = []
        self.walls: list[Facade] = []  # building fronts and fences without planting: people and bikes lean on them
        self.hedges: list[Facade] = []
        self.bushes: list[tuple[np.ndarray, float]] = []
        self.entrances: list[tuple[np.ndarray, float]] = []
        self.benches: list[tuple[np.ndarray, float, float]] = []  # (xy, yaw, half length)

    # ------------------------------------------------------------------ geometry helpers

    def edge(self, s: float, side: int) -> float:
        """|lat| of the outer sidewalk edge at arc length s on `side`."""
        i = int(self.route.index(s))
        low = self.ground.low_left[i] if side > 0 else self.ground.low_right[i]
        return float(low) + self.road.sidewalk(side)

    def at(self, s: float, lat: float) -> np.ndarray:
        return self.route.offset(s, lat)

    def clearance(self, xy: np.ndarray) -> np.ndarray:
        """(N,) distance beyond the outer sidewalk edge (negative on the street)."""
        lat, si = self.ground.lateral(xy)
        si = np.maximum(si, 0)
        left = lat >= 0
        low = np.where(left, self.ground.low_left[si], self.ground.low_right[si])
        sw = np.where(left, self.road.sidewalk_left, self.road.sidewalk_right)
        return np.abs(lat) - low - sw

    def _cells(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        f = np.round((xy - self.ground.origin[None]) / GRID_CELL).astype(np.int64)
        nx, ny = self.occupied.shape
        ok = (f[:, 0] >= 0) & (f[:, 1] >= 0) & (f[:, 0] < nx) & (f[:, 1] < ny)
        return np.clip(f[:, 0], 0, nx - 1), np.clip(f[:, 1], 0, ny - 1), ok

    def free(self, xy: np.ndarray, min_clear: float | None = 0.5) -> bool:
        ix, iy, ok = self._cells(xy)
        if not ok.all() or self.occupied[ix, iy].any():
            return False
        return min_clear is None or bool((self.clearance(xy) >= min_clear).all())

    def mark(self, xy: np.ndarray) -> None:
        ix, iy, ok = self._cells(xy)
        self.occupied[ix[ok], iy[ok]] = True

    @staticmethod
    def rect(center: np.ndarray, yaw: float, half_x: float, half_y: float, step: float = 0.4) -> np.ndarray:
        """(K, 2) points covering a rectangle (for occupancy tests)."""
        xs = np.linspace(-half_x, half_x, max(2, int(np.ceil(2 * half_x / step)) + 1))
        ys = np.linspace(-half_y, half_y, max(2, int(np.ceil(2 * half_y / step)) + 1))
        g = np.stack(np.meshgrid(xs, ys, indexing="ij"), axis=-1).reshape(-1, 2)
        c, s = np.cos(yaw), np.sin(yaw)
        return g @ np.array([[c, s], [-s, c]]) + np.asarray(center)[None]

    @staticmethod
    def disc(center: np.ndarray, radius: float) -> np.ndarray:
        return Layout.rect(center, 0.0, radius, radius, step=max(0.25, radius / 3))

    def z(self, xy: np.ndarray) -> float:
        return float(self.ground.height(np.asarray(xy, float)[None])[0])

    def put(
        self, b: PrimitiveBuilder, xy: np.ndarray, yaw: float, rot: np.ndarray | None = None, dz: float = 0.0
    ):
        pos = np.array([xy[0], xy[1], self.z(xy) + dz])
        self.sets.append(b.build(rot_z(yaw) if rot is None else rot, pos))
        return pos

    def yaw_at(self, s: float) -> float:
        return float(self.route.yaw(s))

    # ------------------------------------------------------------------------- objects

    def tree(self, xy: np.ndarray, style: str | None = None) -> bool:
        rng = self.rng
        style = style or str(rng.choice(list(self.style.tree_styles)))
        ranges = TREE_SHAPES.get(style, TREE_SHAPES["default"])
        radius, height, base, rt = (rng.uniform(lo, hi) for lo, hi in ranges)  # drawn in this order
        if not self.free(self.disc(xy, max(0.6, 0.45 * radius)), min_clear=0.3):
            return False
        self.mark(self.disc(xy, rt + 0.5))
        pos = np.array([xy[0], xy[1], self.z(xy)])
        trunk_id = self.reg.new("tree_trunk", (m.TRUNK,), position=pos)
        crown_id = self.reg.new("tree_crown", (m.VEGETATION,), position=pos + (0, 0, base))
        b = PrimitiveBuilder()
        # bark: plates and furrows of a few centimetres (SemanticKITTI trunks scatter 4 cm along rows)
        bark = Material(refl=rng.uniform(0.28, 0.55), drop=0.02, noise=0.005, depth=rng.uniform(0.06, 0.14),
                        grain=rng.uniform(0.04, 0.08))
        if style == "conifer":
            leaves = m.foliage(rng, dense=True)
            layers = int(rng.integers(3, 5))
            for k in range(layers):
                f = 1.0 - k / layers
                zc = base + height * (k + 0.5) / layers
                b.ellipsoid(
                    (0, 0, zc),
                    (radius * f, radius * f, height / layers * 0.8),
                    m.VEGETATION,
                    crown_id,
                    leaves,
                )
            top = base + 0.7 * height
        else:
            cz = m.add_canopy(b, rng, base, radius, height, crown_id, m.foliage(rng))
            top = cz
        m.add_trunk(b, rt, top, trunk_id, bark)
        if style != "conifer" and rng.random() < TRUNK_SHRUB_P:
            ct.add_trunk_shrub(self, b, rt, pos)
        if style != "conifer" and rng.random() < 0.3:
            # shoots and low twigs on the trunk (epicormic growth): leaves next to the bark
            leaves = m.foliage(rng)
            for _ in range(int(rng.integers(1, 4))):
                ang = rng.uniform(0, 2 * np.pi)
                z = rng.uniform(0.4, max(0.5, min(base, 2.2)))
                r = rng.uniform(0.15, 0.35)
                c = ((rt + 0.6 * r) * np.cos(ang), (rt + 0.6 * r) * np.sin(ang), z)
                b.ellipsoid(c, (r, r, 0.8 * r), m.VEGETATION, crown_id, leaves)
        if style == "young" and rng.random() < 0.5:
            # a tree stake (unknown object class) beside a young trunk
            stake_id = self.reg.new("stake", (m.POLE,), position=pos)
            b.cylinder((rt + 0.12, 0.0, 0.9), 0.03, 0.95, m.POLE, stake_id, Material(refl=0.3, noise=0.005))
        rot = self._tree_variety(b, style, rt, top, trunk_id, bark, pos) if self.extra is not None else None
        yaw = rng.uniform(0, 2 * np.pi)
        self.put(b, xy, yaw, rot=None if rot is None else rot_z(yaw) @ rot)
        return True

    def _tree_variety(
        self, b: PrimitiveBuilder, style: str, rt: float, top: float, trunk_id: int, bark: Material, pos: np.ndarray
    ) -> np.ndarray | None:
        """The varied styles' trees: a second stem, a metal tree guard, a lean; returns the lean's
        rotation (None when upright)."""
        x, st = self.extra, self.style
        if style != "conifer" and x.random() < st.fork_share:  # a second stem from low on the trunk
            z0 = x.uniform(0.6, 1.6)
            ang = x.uniform(0, 2 * np.pi)
            reach = x.uniform(0.6, 1.4)
            b.capsule((0, 0, z0), (reach * np.cos(ang), reach * np.sin(ang), max(z0 + 1.0, 0.9 * top)), 0.7 * rt,
                      m.TRUNK, trunk_id, bark)
        if style in ("young", "mature") and x.random() < st.guard_share:  # a tree guard: bars and two rings
            gid = self.reg.new("tree_guard", (m.OTHER_OBJECT,), position=pos)
            r, h = rt + x.uniform(0.25, 0.4), x.uniform(1.3, 1.8)
            steel = Material(refl=x.uniform(0.2, 0.5), drop=0.05)
            corners = [(r * np.cos(a), r * np.sin(a)) for a in np.linspace(0, 2 * np.pi, 7)[:-1]]
            for cx, cy in corners:
                b.capsule((cx, cy, 0.0), (cx, cy, h), 0.015, m.OTHER_OBJECT, gid, steel)
            for z in (0.5, h):
                for (ax, ay), (bx, by) in zip(corners, corners[1:] + corners[:1], strict=True):
                    b.capsule((ax, ay, z), (bx, by, z), 0.012, m.OTHER_OBJECT, gid, steel)
        if x.random() < st.lean_share:
            return rot_x(np.deg2rad(x.uniform(4.0, 14.0)))
        return None

    def bush(self, xy: np.ndarray, size: float | None = None) -> bool:
        size = size or self.rng.uniform(0.8, 2.6)
        if not self.free(self.disc(xy, 0.5 * size), min_clear=0.2):
            return False
        self.mark(self.disc(xy, 0.55 * size))
        iid = self.reg.new("bush", (m.VEGETATION,), position=(xy[0], xy[1], self.z(xy)))
        b = PrimitiveBuilder()
        m.add_bush(b, self.rng, size, iid, self.style.bush_p)
        if self.extra is not None and self.extra.random() < self.style.varied_bush_share:
            b = PrimitiveBuilder()  # the plain draws above are made all the same, so the layout stays
            fu.add_varied_bush(b, self.extra, size, iid)
        self.put(b, xy, self.rng.uniform(0, 2 * np.pi))
        self.bushes.append((np.asarray(xy, float), 0.5 * size))
        return True

    def hedge(self, s0: float, s1: float, side: int, offset: float) -> None:
        """A hedge from s0 to s1, its street-side face `offset` m beyond the sidewalk edge."""
        rng = self.rng
        length = s1 - s0
        sm = 0.5 * (s0 + s1)
        width, height = rng.uniform(0.5, 1.2), rng.uniform(0.7, 1.8)
        lat = side * (self.edge(sm, side) + offset + width / 2)
        xy = self.at(sm, lat)
        yaw = self.yaw_at(sm)
        pts = self.rect(xy, yaw, length / 2, width / 2)
        if length < 1.0 or not self.free(pts, min_clear=0.0):
            return
        self.mark(pts)
        b = PrimitiveBuilder()
        m.add_hedge(
            b, rng, length, width, height, self.reg.new("hedge", (m.VEGETATION,), position=(*xy, self.z(xy)))
        )
        self.put(b, xy, yaw)
        face = lat - side * width / 2
        towards_street = -side * (self.route.offset(sm, 1.0) - self.route.point(sm))
        self.hedges.append(Facade(np.stack([self.at(s0, face), self.at(s1, face)]), towards_street))

    def parked_car(
        self, xy: np.ndarray, yaw: float, car: m.CarShape | None = None, mark: bool = True
    ) -> np.ndarray | None:
        """A parked car (drawn unless given) at `xy` heading `yaw`; its footprint, or None when it
        does not fit. mark=False leaves the footprint for the caller to mark (a row of cars whose
        bumpers may touch)."""
        car = car or self.style.draw_car(self.rng, extra=self.extra)
        pad = (0.2, 0.15) if mark else (0.0, 0.0)
        pts = self.rect(xy, yaw, car.overall_length / 2 + pad[0], car.width / 2 + pad[1], step=0.3)
        if not self.free(pts, min_clear=None) or not self.ground.low(pts).all():
            return None
        if mark:
            self.mark(pts)
        iid = self.reg.new("car", (m.CAR,), position=(xy[0], xy[1], self.z(xy)), dark=car.dark)
        b = PrimitiveBuilder()
        m.add_car(b, car, m.CAR, iid)
        self.put(b, xy, yaw, rot=ground_frame(self.ground, xy, yaw))
        return pts

    def small(
        self, xy: np.ndarray, what: str, yaw: float | None = None, min_clear: float | None = None
    ) -> bool:
        """Street furniture: lamp, sign, cone, bin, bench, bollard, bicycle, person."""
        rng = self.rng
        yaw = rng.uniform(0, 2 * np.pi) if yaw is None else yaw
        if what in ("bench", "bicycle"):  # long and narrow: a rectangle along the object's x axis
            half = (1.05, 0.3) if what == "bench" else (0.6, 0.15)
            pts = self.rect(xy, yaw, *half, step=0.3)
        else:
            radius = {"lamp": 0.3, "sign": 0.3, "cone": 0.25, "bin": 0.4, "bollard": 0.2, "person": 0.35}[
                what
            ]
            pts = self.disc(xy, radius)
        if not self.free(pts, min_clear=min_clear):
            return False
        self.mark(pts)
        b = PrimitiveBuilder()
        pos = (xy[0], xy[1], self.z(xy))
        if what == "lamp":
            fu.add_lamp(b, rng, self.reg.new("lamp", (m.POLE,), position=pos))
        elif what == "sign":
            fu.add_sign(b, rng, self.reg.new("sign", (m.POLE, m.TRAFFIC_SIGN), position=pos))
        elif what == "cone":
            fu.add_cone(b, self.reg.new("cone", (m.OTHER_OBJECT,), position=pos))
        elif what == "bin":
            fu.add_bin(b, rng, self.reg.new("bin", (m.OTHER_OBJECT,), position=pos))
        elif what == "bench":
            fu.add_bench(b, rng, self.reg.new("bench", (m.OTHER_OBJECT,), position=pos))
            self.benches.append((np.asarray(xy, float), float(yaw), 0.8))
        elif what == "bollard":
            fu.add_bollard(b, self.reg.new("bollard", (m.OTHER_OBJECT,), position=pos))
        elif what == "bicycle":
            m.add_bicycle(
                b,
                m.BICYCLE,
                self.reg.new("bicycle", (m.BICYCLE,), position=pos),
                Material(refl=rng.uniform(0.2, 0.6)),
            )
        else:
            iid = self.reg.new("person", (m.PERSON,), position=pos)
            m.add_person(
                b, self.style.draw_person(rng), m.PERSON,
                iid, rng.uniform(0, 2 * np.pi), rng.uniform(0.0, 0.12)
            )
        self.put(b, xy, yaw)
        return True

    def fence(self, s0: float, s1: float, side: int, offset: float) -> None:
        length = s1 - s0
        sm = 0.5 * (s0 + s1)
        xy = self.at(sm, side * (self.edge(sm, side) + offset))
        yaw = self.yaw_at(sm)
        pts = self.rect(xy, yaw, length / 2, 0.1)
        if not self.free(pts, min_clear=0.3):
            return
        self.mark(pts)
        b = PrimitiveBuilder()
        h = fu.add_fence(
            b, self.rng, length, self.reg.new("fence", (m.FENCE,), position=(xy[0], xy[1], self.z(xy)))
        )
        self.put(b, xy, yaw)
        out = -side if self.rng.random() < 0.7 else side  # planting mostly on the street side
        planting = ct.draw_planting(self.rng, -length / 2, length / 2, 1.3, h, ct.FENCE_PLANTING_P)
        if planting is not None:
            foot = ct.planting_footprint(self, planting, xy, yaw, out * 0.05, out)
            if self.free(foot, min_clear=0.0):
                self.mark(foot)
                ct.build_planting(self, planting, xy, yaw, out * 0.05, out)
                return
        normal = -side * (self.route.offset(sm, 1.0) - self.route.point(sm))
        self.walls.append(Facade(np.stack([self.at(s0, side * (self.edge(sm, side) + offset - 0.05)),
                                           self.at(s1, side * (self.edge(sm, side) + offset - 0.05))]),
                                 normal, wall=False))
