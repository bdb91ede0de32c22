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
from research.simulation import models as m
from research.simulation.actors import ground_frame
from research.simulation.ground import GRID_CELL, GroundModel
from research.simulation.route import SAMPLE_STEP, Route
from research.simulation.shapes import Material, PrimitiveBuilder, PrimitiveSet, concat, rot_x, rot_z
from research.simulation.style import STYLES, CampusStyle

TRUNK_SHRUB_P = 0.25  # trees with a shrub grown against the trunk
GARDEN_FENCE_P = 0.5  # hedge stretches with a fence behind the sidewalk (planting against it)
STRETCH_TYPES = ("avenue", "frontage", "hedges", "bays", "lot", "open")
STRETCH_P = (0.2, 0.17, 0.15, 0.26, 0.12, 0.10)
BAY_WIDTH = 2.3


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
class Facade:
    """A building front a pedestrian can walk along: end points (2, 2) and outward normal (2,)."""

    ends: np.ndarray
    normal: np.ndarray
    wall: bool = True  # a building's wall (False: a fence)


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


class Layout:
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
        if style == "young":
            radius, height, base, rt = (
                rng.uniform(0.9, 1.6),
                rng.uniform(1.6, 2.8),
                rng.uniform(1.6, 2.4),
                rng.uniform(0.06, 0.11),
            )
        elif style == "conifer":
            radius, height, base, rt = (
                rng.uniform(1.2, 2.2),
                rng.uniform(4.0, 8.0),
                rng.uniform(0.6, 1.6),
                rng.uniform(0.12, 0.25),
            )
        elif style == "wide":
            radius, height, base, rt = (
                rng.uniform(3.2, 5.0),
                rng.uniform(3.5, 6.0),
                rng.uniform(2.4, 3.6),
                rng.uniform(0.25, 0.42),
            )
        else:
            radius, height, base, rt = (
                rng.uniform(2.0, 3.4),
                rng.uniform(3.0, 5.5),
                rng.uniform(2.0, 3.4),
                rng.uniform(0.14, 0.3),
            )
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
            m.add_varied_bush(b, self.extra, size, iid)
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

    def building(
        self, xy: np.ndarray, yaw: float, length: float, depth: float, height: float, walkable: bool
    ) -> bool:
        """A building whose front (local +y) faces the street at `xy`; False when it does not fit.
        Its front wall may carry planting (`contacts`): then people do not walk along it."""
        rng = self.rng
        wing = rng.random() < 0.35
        wing_w = rng.uniform(6.0, min(14.0, 0.6 * length)) if wing else 0.0
        wing_d = rng.uniform(6.0, 16.0) if wing else 0.0
        wing_side = rng.choice([-1, 1])
        centre_local = np.array([0.0, -depth / 2])
        c, s = np.cos(yaw), np.sin(yaw)
        rot2 = np.array([[c, -s], [s, c]])
        main_pts = self.rect(xy + rot2 @ centre_local, yaw, length / 2, depth / 2)
        pts = [main_pts]
        if wing:
            wc = np.array([wing_side * (length / 2 - wing_w / 2), -depth - wing_d / 2 + 0.1])
            pts.append(self.rect(xy + rot2 @ wc, yaw, wing_w / 2, wing_d / 2))
        allpts = np.concatenate(pts)
        if not self.free(allpts, min_clear=0.6):
            return False
        room = float(self.clearance(np.stack([xy + rot2 @ np.array([x, 0.0]) for x in (-length / 2, 0.0, length / 2)])).min())
        planting = ct.draw_planting(rng, -length / 2 + 0.3, length / 2 - 0.3, room, height, ct.WALL_PLANTING_P)
        if planting is not None:
            foot = ct.planting_footprint(self, planting, xy, yaw, 0.0, 1)
            if self.free(foot, min_clear=0.0):
                self.mark(foot)
            else:
                planting = None
        self.mark(allpts)
        ground_z = self.ground.height(allpts)
        z0 = self.z(xy)
        iid = self.reg.new("building", (m.BUILDING,), position=(xy[0], xy[1], z0))
        glass = rng.random() < self.style.glass_share
        if glass:
            wall = Material(refl=rng.uniform(0.15, 0.3), drop=0.02, spec=0.3)
        else:  # plaster, brick, concrete: SemanticKITTI's walls return 0.28-0.64 (10th-90th percentile)
            wall = Material(refl=rng.uniform(0.32, 0.7), drop=0.01, spec=0.05)
        facade = None if glass else m.draw_facade(rng)
        b = PrimitiveBuilder()
        bottom = float(ground_z.min()) - z0 - 0.6
        entrance = self._building_blocks(b, rng, iid, wall, facade, length, depth, height, bottom)
        if wing:
            x0 = wing_side * length / 2 - (wing_w if wing_side > 0 else 0.0)
            _block(b, iid, wall, None, x0, x0 + wing_w, -depth - wing_d, -depth + 0.1, bottom,
                   height * rng.uniform(0.6, 1.3))
        if rng.random() < 0.25 and length > 12.0:
            tw = rng.uniform(5.0, 10.0)
            tx = rng.uniform(-length / 2 + tw / 2, length / 2 - tw / 2)
            _block(b, iid, wall, None, tx - tw / 2, tx + tw / 2, -depth + 1.0, -1.0, bottom,
                   height + rng.uniform(3.0, 9.0))
        self.put(b, xy, yaw, dz=0.0)
        self.entrances.append((xy + rot2 @ entrance, yaw))
        front = Facade(np.stack([xy + rot2 @ np.array([x, 0.0]) for x in (-length / 2 + 0.5, length / 2 - 0.5)]),
                       rot2 @ np.array([0.0, 1.0]))
        if planting is not None:
            ct.build_planting(self, planting, xy, yaw, 0.0, 1)
        else:
            self.walls.append(front)
            if walkable:
                self.facades.append(front)
        return True

    def _building_blocks(
        self, b: PrimitiveBuilder, rng: np.random.Generator, iid: int, wall: Material, facade: m.FacadeShape | None,
        length: float, depth: float, height: float, bottom: float,
    ) -> np.ndarray:
        """The main blocks (with a recessed entrance under an overhang on pillars, or plain); returns
        the local xy in front of the entrance."""
        if not (length > 14.0 and rng.random() < 0.5):
            _block(b, iid, wall, facade, -length / 2, length / 2, -depth, 0.0, bottom, height)
            return np.array([rng.uniform(-length / 3, length / 3), 0.8])
        rw = rng.uniform(4.0, min(12.0, length - 6.0))
        xa = rng.uniform(-length / 2 + 2.5, length / 2 - 2.5 - rw)
        xb = xa + rw
        rd = rng.uniform(1.5, 4.0)
        _block(b, iid, wall, facade, -length / 2, xa, -depth, 0.0, bottom, height)
        _block(b, iid, wall, facade, xb, length / 2, -depth, 0.0, bottom, height)
        _block(b, iid, wall, None, xa, xb, -depth, -rd, bottom, height)
        if height > 5.0 and rng.random() < 0.6:
            # An upper floor over the recess, carried by pillars: a covered entrance.
            b.box(((xa + xb) / 2, -rd / 2, (3.4 + height) / 2), (rw / 2, rd / 2, (height - 3.4) / 2), m.BUILDING,
                  iid, wall)
            for x in np.arange(xa + 0.5, xb - 0.2, 3.0):
                b.cylinder((x, -0.4, (bottom + 3.4) / 2), rng.uniform(0.18, 0.3), (3.4 - bottom) / 2, m.BUILDING,
                           iid, wall)
        return np.array([(xa + xb) / 2, 0.5])

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
            m.add_lamp(b, rng, self.reg.new("lamp", (m.POLE,), position=pos))
        elif what == "sign":
            m.add_sign(b, rng, self.reg.new("sign", (m.POLE, m.TRAFFIC_SIGN), position=pos))
        elif what == "cone":
            m.add_cone(b, self.reg.new("cone", (m.OTHER_OBJECT,), position=pos))
        elif what == "bin":
            m.add_bin(b, rng, self.reg.new("bin", (m.OTHER_OBJECT,), position=pos))
        elif what == "bench":
            m.add_bench(b, rng, self.reg.new("bench", (m.OTHER_OBJECT,), position=pos))
            self.benches.append((np.asarray(xy, float), float(yaw), 0.8))
        elif what == "bollard":
            m.add_bollard(b, self.reg.new("bollard", (m.OTHER_OBJECT,), position=pos))
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
        h = m.add_fence(
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


def _block(
    b: PrimitiveBuilder, iid: int, wall: Material, facade: m.FacadeShape | None, x0: float, x1: float, y0: float,
    y1: float, bottom: float, top: float,
) -> None:
    """A building block x0..x1, y0..y1 (local) from `bottom` to `top`; with a facade, its front
    (y1) is a wall with recessed windows (`models.add_facade`)."""
    if facade is not None:
        models_front = y1 - facade.recess
        sub = PrimitiveBuilder()
        m.add_facade(sub, facade, x0, x1, bottom, top, iid, wall)
        sub.shift(0.0, y1)
        b.extend(sub)
        y1 = models_front
    b.box(((x0 + x1) / 2, (y0 + y1) / 2, (bottom + top) / 2), ((x1 - x0) / 2, (y1 - y0) / 2, (top - bottom) / 2),
          m.BUILDING, iid, wall)


# --------------------------------------------------------------------------- the plan


def populate(lay: Layout, stretches: list[Stretch], crossings: np.ndarray) -> None:
    """Fill every stretch, then the background, street furniture and standing people."""
    rng = lay.rng
    for st in stretches:
        _FILL[st.kind](lay, st)
    _background_buildings(lay)
    _scattered_vegetation(lay)
    _lamps(lay)
    _furniture(lay, stretches)
    for sc in crossings:
        for side in (1, -1):
            curb_lat = side * (lay.edge(sc, side) - lay.road.sidewalk(side) + 0.35)
            lay.small(lay.at(sc - 6.0, curb_lat), "sign", yaw=lay.yaw_at(sc) + np.pi / 2, min_clear=None)
            for k in range(int(rng.integers(0, 5))):
                lay.small(
                    lay.at(sc - 3.0 - 1.5 * k, side * (lay.edge(sc, side) + 0.3)), "bollard", min_clear=0.0
                )
    _standing_people(lay)
    ct.lean_on_walls(lay, lay.walls)
    if lay.extra is not None:
        _varied_extras(lay, stretches)


EXTRA_FURNITURE_P = {"hydrant": 0.25, "postbox": 0.2, "cabinet": 0.3, "planter": 0.25, "statue": 0.12}
KIOSK_P = 0.2  # per open, frontage, avenue or hedges stretch (times `extra_furniture`)


def _varied_extras(lay: Layout, stretches: list[Stretch]) -> None:
    """The varied styles' extra kinds, placed last so that the plain layout stays as it is:
    people sitting on benches; hydrants, post boxes, cabinets, planters and statues along the
    sidewalks; kiosks and sheds beside them."""
    x, st = lay.extra, lay.style
    for xy, yaw, half in lay.benches:
        if x.random() < st.sitting_share:
            c, s = np.cos(yaw), np.sin(yaw)
            along = x.uniform(-half + 0.3, half - 0.3)
            p = xy + np.array([c * along + s * 0.08, s * along - c * 0.08])
            b = PrimitiveBuilder()
            iid = lay.reg.new("person", (m.PERSON,), position=(p[0], p[1], lay.z(p)))
            m.add_sitting_person(b, st.draw_person(x), m.PERSON, iid)
            lay.put(b, p, yaw + np.pi / 2)
    for sr in stretches:
        side = sr.side
        for what, prob in EXTRA_FURNITURE_P.items():
            if x.random() >= prob * st.extra_furniture:
                continue
            s = x.uniform(sr.s0, sr.s1)
            p = lay.at(s, side * (lay.edge(s, side) + x.uniform(0.3, 1.5)))
            if not lay.free(lay.disc(p, 0.45), min_clear=0.0):
                continue
            lay.mark(lay.disc(p, 0.45))
            b = PrimitiveBuilder()
            pos = (p[0], p[1], lay.z(p))
            iid = lay.reg.new(what, (m.OTHER_OBJECT,), position=pos)
            if what == "hydrant":
                m.add_hydrant(b, iid)
            elif what == "postbox":
                m.add_postbox(b, x, iid)
            elif what == "cabinet":
                m.add_cabinet(b, x, iid)
            elif what == "planter":
                m.add_planter(b, x, iid, lay.reg.new("bush", (m.VEGETATION,), position=pos))
            else:
                m.add_statue(b, x, iid)
            lay.put(b, p, lay.yaw_at(s) + x.uniform(-0.3, 0.3))
        if sr.kind in ("open", "frontage", "avenue", "hedges") and x.random() < KIOSK_P * st.extra_furniture:
            s = x.uniform(sr.s0, sr.s1)
            p = lay.at(s, side * (lay.edge(s, side) + x.uniform(2.0, 5.0)))
            hx, hy = x.uniform(1.0, 2.25), x.uniform(0.9, 1.5)
            yaw = lay.yaw_at(s) + (np.pi if side > 0 else 0.0)
            pts = lay.rect(p, yaw, hx + 0.2, hy + 0.45)
            if lay.free(pts, min_clear=0.3):
                lay.mark(pts)
                b = PrimitiveBuilder()
                m.add_kiosk(b, x, lay.reg.new("kiosk", (m.BUILDING,), position=(p[0], p[1], lay.z(p))), hx, hy)
                lay.put(b, p, yaw)


def _furniture(lay: Layout, stretches: list[Stretch]) -> None:
    """Bins, benches, bike racks, signs and fences along the sidewalks (the 'unknown' class)."""
    rng = lay.rng
    for st in stretches:
        side = st.side
        facing = lay.yaw_at(st.s0) + (np.pi if side > 0 else 0.0)
        if rng.random() < 0.35:
            s = rng.uniform(st.s0, st.s1)
            lay.small(lay.at(s, side * (lay.edge(s, side) + 0.5)), "bin", min_clear=0.0)
        if rng.random() < 0.25:
            s = rng.uniform(st.s0, st.s1)
            lay.small(lay.at(s, side * (lay.edge(s, side) + 0.7)), "bench", yaw=facing, min_clear=0.2)
        if rng.random() < 0.2:
            s = rng.uniform(st.s0, st.s1)
            i = int(lay.route.index(s))
            low = float(lay.ground.low_left[i] if side > 0 else lay.ground.low_right[i])
            lay.small(lay.at(s, side * (low + 0.4)), "sign", yaw=lay.yaw_at(s) + np.pi / 2, min_clear=None)
        if rng.random() < 0.15:
            s = rng.uniform(st.s0, st.s1 - 4.0)
            for k in range(int(rng.integers(2, 6))):
                lay.small(
                    lay.at(s + 0.8 * k, side * (lay.edge(s, side) + 0.8)),
                    "bicycle",
                    yaw=facing + np.pi / 2,
                    min_clear=0.0,
                )
        if rng.random() < 0.15:
            a = rng.uniform(st.s0, max(st.s0, st.s1 - 10.0))
            lay.fence(a, min(st.s1, a + rng.uniform(8.0, 30.0)), side, rng.uniform(2.5, 8.0))


def _trees_in_row(
    lay: Layout, st: Stretch, offset: tuple[float, float], spacing: tuple[float, float], p: float = 1.0
) -> None:
    rng = lay.rng
    s = st.s0 + rng.uniform(2.0, 6.0)
    style = str(rng.choice(list(lay.style.row_tree_styles)))
    while s < st.s1 - 2.0:
        if rng.random() < p:
            lat = st.side * (lay.edge(s, st.side) + rng.uniform(*offset))
            lay.tree(lay.at(s, lat), style if rng.random() < 0.8 else None)
        s += rng.uniform(*spacing)


def _avenue(lay: Layout, st: Stretch) -> None:
    rng = lay.rng
    _trees_in_row(lay, st, (1.3, 2.0), (7.0, 12.0))
    for _ in range(int(rng.integers(1, 5))):
        s = rng.uniform(st.s0, st.s1)
        lay.bush(lay.at(s, st.side * (lay.edge(s, st.side) + rng.uniform(0.8, 4.0))))
    if rng.random() < 0.4:
        a = rng.uniform(st.s0, st.s0 + 10)
        lay.hedge(a, min(st.s1, a + rng.uniform(8, 30)), st.side, rng.uniform(4.0, 7.0))
    if rng.random() < 0.4:
        s = rng.uniform(st.s0, st.s1)
        lay.small(
            lay.at(s, st.side * (lay.edge(s, st.side) + 0.9)),
            "bench",
            yaw=lay.yaw_at(s) + (np.pi if st.side > 0 else 0.0),
            min_clear=0.3,
        )


def _frontage(lay: Layout, st: Stretch) -> None:
    rng = lay.rng
    s = st.s0 + rng.uniform(0.0, 4.0)
    while st.s1 - s > 12.0:
        length = min(rng.uniform(14.0, 45.0), st.s1 - s)
        sm = s + length / 2
        setback = rng.uniform(0.8, 3.0)
        hedge = setback > 2.2 and rng.random() < 0.4
        lat = st.side * (lay.edge(sm, st.side) + setback)
        yaw = lay.yaw_at(sm) + (np.pi if st.side > 0 else 0.0)  # local +y towards the street
        walkers = len(lay.facades)
        ok = lay.building(
            lay.at(sm, lat), yaw, length, rng.uniform(10.0, 24.0), rng.uniform(4.0, 18.0), walkable=not hedge
        )
        if ok and hedge:
            lay.hedge(s + 1.0, s + length - 1.0, st.side, 0.3)
        if ok and rng.random() < 0.35:
            if len(lay.facades) > walkers:
                lay.facades.pop()  # the rack stands where people would walk along the wall
            sb = s + rng.uniform(2.0, length - 2.0)
            n = int(rng.integers(2, 7))
            ct.add_rack(lay, lay.at(sb, st.side * (lay.edge(sb, st.side) + 0.75)), lay.yaw_at(sb), n, 0.8)
            for k in range(n):
                p = lay.at(sb + 0.8 * k, st.side * (lay.edge(sb, st.side) + 0.75))
                lay.small(p, "bicycle", yaw=lay.yaw_at(sb) + np.pi / 2, min_clear=0.0)
        s += length + rng.uniform(3.0, 15.0)


def _hedges(lay: Layout, st: Stretch) -> None:
    if lay.rng.random() < GARDEN_FENCE_P:
        lay.fence(st.s0 + 1.0, st.s1 - 1.0, st.side, lay.rng.uniform(1.0, 1.8))
    _hedge_row(lay, st, 0.3)
    _trees_in_row(lay, st, (3.0, 6.0), (8.0, 15.0), p=0.6)


def _bays(lay: Layout, st: Stretch) -> None:
    """Cars parked along the curb bumper to bumper (`contacts.bumper_gap`), a few bays empty."""
    rng = lay.rng
    lat = st.side * (lay.road.road_half + BAY_WIDTH / 2)
    s, end = st.s0 + 5.0, -np.inf  # next free arc length; where the last parked car ends
    row: list[np.ndarray] = []
    while s < st.s1 - 9.0:
        if rng.random() < 0.85:
            # the plain style's car sets the spacing, so the varied styles keep the plain draws
            plain = lay.style.draw_car(rng)
            car = lay.style.vary_car(plain, lay.extra)
            sc = s + plain.overall_length / 2
            yaw = lay.yaw_at(sc) + (np.pi if st.side > 0 else 0.0)
            if rng.random() < 0.12:
                yaw += np.pi
            xy = lay.at(sc, lat + rng.uniform(-0.1, 0.1))
            if sc - car.overall_length / 2 >= end:  # a longer varied car may not fit
                foot = lay.parked_car(xy, yaw, car=car, mark=False)
                if foot is not None:
                    row.append(foot)
                    end = sc + car.overall_length / 2
            s += plain.overall_length + ct.bumper_gap(rng)
        else:
            s += rng.uniform(5.0, 6.5)  # an empty bay
    for foot in row:  # marked after the row, so that neighbours may touch
        lay.mark(foot)
    if rng.random() < 0.5:
        _hedge_row(lay, st, 0.3)
        _trees_in_row(lay, st, (3.0, 5.0), (9.0, 15.0), p=0.6)
    else:
        _trees_in_row(lay, st, (1.3, 2.5), (9.0, 15.0), p=0.6)


def _hedge_row(lay: Layout, st: Stretch, offset: float) -> None:
    """Hedge segments of 4-18 m with gaps of 1-4 m along the stretch."""
    rng = lay.rng
    s = st.s0 + rng.uniform(0.0, 3.0)
    while st.s1 - s > 4.0:
        length = min(rng.uniform(4.0, 18.0), st.s1 - s)
        lay.hedge(s, s + length, st.side, offset)
        s += length + rng.uniform(1.0, 4.0)


def _lot(lay: Layout, st: Stretch) -> None:
    rng = lay.rng
    i = int(lay.route.index(0.5 * (st.s0 + st.s1)))
    low = float(lay.ground.low_left[i] if st.side > 0 else lay.ground.low_right[i])
    rows = [lay.road.road_half + 3.0 + 2.5, low - 0.3 - 2.5]
    occupancy = rng.uniform(0.6, 0.9)
    for r, lat_abs in enumerate(rows):
        s, end = st.s0 + 6.0, -np.inf
        row: list[np.ndarray] = []
        while s < st.s1 - 6.0:
            if rng.random() < occupancy:
                plain = lay.style.draw_car(rng)
                car = lay.style.vary_car(plain, lay.extra)
                nose = 1 if (r == 0) == (rng.random() < 0.7) else -1
                yaw = lay.yaw_at(s) + st.side * nose * np.pi / 2
                xy = lay.at(s, st.side * (lat_abs + rng.uniform(-0.2, 0.2)))
                turn = rng.uniform(-0.04, 0.04)
                if s - car.overall_width / 2 >= end:
                    foot = lay.parked_car(xy, yaw + turn, car=car, mark=False)
                    if foot is not None:
                        row.append(foot)
                        end = s + car.overall_width / 2
                s += plain.overall_width + rng.uniform(0.05, 0.65)  # mirror to mirror
            else:
                s += rng.uniform(2.4, 2.7)  # an empty space
        for foot in row:
            lay.mark(foot)
    if rng.random() < 0.6:
        s = rng.uniform(st.s0 + 6, st.s1 - 6)
        for k in range(int(rng.integers(2, 6))):
            lay.small(lay.at(s + 1.6 * k, st.side * (0.5 * (rows[0] + rows[1]))), "cone", min_clear=None)
    if rng.random() < 0.6:
        _hedge_row(lay, st, 0.3)
    for s in np.arange(st.s0 + 8.0, st.s1 - 4.0, rng.uniform(12.0, 20.0)):
        lay.small(
            lay.at(s, st.side * (low + 0.6)),
            "lamp",
            yaw=lay.yaw_at(s) + (np.pi if st.side > 0 else 0.0),
            min_clear=None,
        )


def _open(lay: Layout, st: Stretch) -> None:
    rng = lay.rng
    for _ in range(int(rng.integers(2, 7))):
        s = rng.uniform(st.s0, st.s1)
        lay.tree(lay.at(s, st.side * (lay.edge(s, st.side) + rng.uniform(1.5, 15.0))))
    for _ in range(int(rng.integers(2, 7))):
        s = rng.uniform(st.s0, st.s1)
        lay.bush(lay.at(s, st.side * (lay.edge(s, st.side) + rng.uniform(0.8, 10.0))))
    for what in ("bin", "bench", "sign"):
        if rng.random() < 0.4:
            s = rng.uniform(st.s0, st.s1)
            lay.small(
                lay.at(s, st.side * (lay.edge(s, st.side) + rng.uniform(0.5, 2.0))), what, min_clear=0.2
            )
    if rng.random() < 0.4:
        a = rng.uniform(st.s0, st.s1 - 8.0)
        lay.fence(a, min(st.s1, a + rng.uniform(8.0, 30.0)), st.side, rng.uniform(2.0, 10.0))
    if rng.random() < 0.25:
        # Cones around a work spot on the grass by the sidewalk.
        s = rng.uniform(st.s0 + 3, st.s1 - 6)
        for k in range(int(rng.integers(3, 7))):
            lay.small(lay.at(s + 1.5 * k, st.side * (lay.edge(s, st.side) + 0.6)), "cone", min_clear=0.0)


_FILL = {
    "avenue": _avenue,
    "frontage": _frontage,
    "hedges": _hedges,
    "bays": _bays,
    "lot": _lot,
    "open": _open,
}


def _background_buildings(lay: Layout) -> None:
    """Two rows of buildings behind the stretches: 4-20 m and 22-50 m beyond the sidewalk."""
    rng = lay.rng
    for near, far in ((4.0, 20.0), (22.0, 50.0)):
        for a, b in lay.route.straight_runs(margin=0.0):
            for side in (1, -1):
                s = a + rng.uniform(0.0, 8.0)
                while s < b:
                    length = rng.uniform(12.0, 50.0)
                    sm = s + length / 2
                    yaw = lay.yaw_at(sm) + (np.pi if side > 0 else 0.0) + rng.uniform(-0.15, 0.15)
                    depth, height = rng.uniform(10.0, 28.0), rng.uniform(4.0, 22.0)
                    for _ in range(3):
                        lat = side * (lay.edge(sm, side) + rng.uniform(near, far))
                        if lay.building(lay.at(sm, lat), yaw, length, depth, height, walkable=False):
                            break
                    s += length + rng.uniform(4.0, 20.0)


def _scattered_vegetation(lay: Layout) -> None:
    rng = lay.rng
    n = int(lay.route.length / 3)
    for _ in range(n):
        s = rng.uniform(0, lay.route.length)
        side = 1 if rng.random() < 0.5 else -1
        xy = lay.at(s, side * (lay.edge(s, side) + rng.uniform(1.5, 8.0) ** 1.6))
        if rng.random() < 0.55:
            lay.tree(xy)
        else:
            lay.bush(xy)


def _lamps(lay: Layout) -> None:
    rng = lay.rng
    for side in (1, -1):
        if rng.random() < 0.3:
            continue
        s = rng.uniform(0, 10)
        step = rng.uniform(25.0, 40.0)
        while s < lay.route.length:
            i = int(lay.route.index(s))
            low = float(lay.ground.low_left[i] if side > 0 else lay.ground.low_right[i])
            lay.small(
                lay.at(s, side * (low + 0.35)),
                "lamp",
                yaw=lay.yaw_at(s) + (np.pi if side > 0 else 0.0),
                min_clear=None,
            )
            s += step


def _standing_people(lay: Layout) -> None:
    """People standing still: by bushes (the classifier's hard case), at entrances, chatting."""
    rng = lay.rng
    for xy, r in lay.bushes:
        if rng.random() < 0.15:
            ang = rng.uniform(0, 2 * np.pi)
            p = xy + (r + rng.uniform(0.25, 0.5)) * np.array([np.cos(ang), np.sin(ang)])
            lay.small(p, "person", yaw=ang + np.pi + rng.uniform(-1, 1), min_clear=None)
    for xy, _yaw in lay.entrances:
        if rng.random() < 0.3:
            for k in range(int(rng.integers(1, 4))):
                ang = 2 * np.pi * k / 3 + rng.uniform(-0.4, 0.4)
                p = xy + 0.7 * np.array([np.cos(ang), np.sin(ang)])
                lay.small(p, "person", yaw=ang + np.pi, min_clear=None)


def static_primitives(lay: Layout) -> PrimitiveSet:
    return concat(lay.sets)
