"""Things that touch: the contacts that join two objects into one segment on real streets.

On real scans (SemanticKITTI sequence 00) most impure segments are hedges and climbers against
building walls, shrubs against tree trunks and cars parked bumper to bumper (docs/simulator.md).
The campus shows them too:

- planting along a wall or a fence (`plan_planting`, `build_planting`): a hedge flush against it
  or 0.1-1 m in front of it, climbers (ivy) on it, or a row of shrubs touching it;
- a shrub grown against a tree trunk (`add_trunk_shrub`);
- people leaning on walls and fences, bicycles leaning on walls (`lean_on_walls`);
- bike racks whose hoops touch the bikes parked in them (`add_rack`).
Parked cars stand bumper to bumper in layout's bays and lots (`bumper_gap`).

Host-local frames: a host (wall, fence) runs along local x; its face is at local y = `face`, and
the planting grows towards `out` (+1 or -1) from it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from research.simulation import models as m
from research.simulation.shapes import Material, PrimitiveBuilder, rot_x, rot_y, rot_z

if TYPE_CHECKING:
    from research.simulation.layout import Facade, Layout

PLANTING_KINDS = ("hedge_flush", "hedge_gap", "ivy", "shrub_row")  # instance kinds too
WALL_PLANTING_P = (0.35, 0.15, 0.15, 0.2)  # of a building front; the rest have none
FENCE_PLANTING_P = (0.3, 0.05, 0.2, 0.1)
TOUCHING_CARS = 0.15  # parked cars whose bumper touches the next car's


@dataclass(frozen=True)
class Planting:
    """Vegetation along a host, in the host's frame: x0..x1 along it, `gap` m off its face,
    `width` m deep, `height` m high (from the ground); kind one of PLANTING_KINDS (ivy grows on
    the face, `gap` 0)."""

    kind: str
    x0: float
    x1: float
    gap: float
    width: float
    height: float


def bumper_gap(rng: np.random.Generator) -> float:
    """Metres between two parked cars in a row: touching (0-5 cm) or 0.2-0.8 m."""
    if rng.random() < TOUCHING_CARS:
        return float(rng.uniform(0.0, 0.05))
    return float(rng.uniform(0.2, 0.8))


def draw_planting(
    rng: np.random.Generator, x0: float, x1: float, room: float, host_height: float, p: tuple[float, ...]
) -> Planting | None:
    """A planting along x0..x1 of a host `host_height` high with `room` m free in front of it,
    kind drawn with probabilities `p` (PLANTING_KINDS order); None for none or no room."""
    u = rng.random()
    cum = np.cumsum(p)
    if u >= cum[-1]:
        return None
    kind = PLANTING_KINDS[int(np.searchsorted(cum, u, "right"))]
    length = x1 - x0
    share = rng.uniform(0.6, 1.0)
    a = x0 + rng.uniform(0.0, (1.0 - share) * length)
    b = a + share * length
    if kind == "ivy":
        h = min(host_height, rng.uniform(1.5, 7.0))
        return Planting(kind, a, b, 0.0, rng.uniform(0.1, 0.25), h)
    if kind == "shrub_row":
        return Planting(kind, a, b, 0.0, rng.uniform(0.7, 1.4), rng.uniform(0.7, 1.6))
    gap = rng.uniform(0.0, 0.05) if kind == "hedge_flush" else rng.uniform(0.1, 1.0)
    width = min(rng.uniform(0.5, 1.2), room - gap - 0.1)
    if width < 0.4:
        return None
    return Planting(kind, a, b, gap, width, rng.uniform(0.8, 2.0))


def planting_footprint(lay: Layout, pl: Planting, xy: np.ndarray, yaw: float, face: float, out: int) -> np.ndarray:
    """(K, 2) scene points covering the planting's ground (occupancy), host at `xy`, `yaw`."""
    y_mid = face + out * (pl.gap + 0.5 * pl.width)
    centre = _host_to_scene(xy, yaw, 0.5 * (pl.x0 + pl.x1), y_mid)
    return lay.rect(centre, yaw, 0.5 * (pl.x1 - pl.x0), 0.5 * pl.width)


def build_planting(lay: Layout, pl: Planting, xy: np.ndarray, yaw: float, face: float, out: int) -> None:
    """Put the planting's primitives on the campus, in pieces of <= 6 m that each stand on the
    ground under them; each hedge, climber and shrub is its own instance."""
    rng = lay.rng
    y_mid = face + out * (pl.gap + 0.5 * pl.width)
    pieces = max(1, int(np.ceil((pl.x1 - pl.x0) / 6.0)))
    edges = np.linspace(pl.x0, pl.x1, pieces + 1)
    leaves = m.foliage(rng, dense=pl.kind != "ivy", climber=pl.kind == "ivy")
    iid = 0
    for a, b in zip(edges[:-1], edges[1:], strict=True):
        if pl.kind == "shrub_row":
            _add_shrubs(lay, pl, a, b, xy, yaw, y_mid)
            continue
        p = _host_to_scene(xy, yaw, 0.5 * (a + b), y_mid)
        z = lay.z(p)
        if iid == 0:  # one hedge or climber along the host, built in pieces
            iid = lay.reg.new(pl.kind, (m.VEGETATION,), position=(p[0], p[1], z))
        sink = 0.1 + max(0.0, z - min(lay.z(_host_to_scene(xy, yaw, x, y_mid)) for x in (a, b)))
        bld = PrimitiveBuilder()
        bld.box((0.0, 0.0, 0.5 * (pl.height - sink)), (0.5 * (b - a), 0.5 * pl.width, 0.5 * (pl.height + sink)),
                m.VEGETATION, iid, leaves)
        lay.put(bld, p, yaw)


def _host_to_scene(xy: np.ndarray, yaw: float, x: float, y: float) -> np.ndarray:
    """(2,) scene xy of the point (x, y) of a host frame at `xy` turned by `yaw`."""
    c, s = np.cos(yaw), np.sin(yaw)
    return np.asarray(xy) + np.array([c * x - s * y, s * x + c * y])


def _add_shrubs(lay: Layout, pl: Planting, a: float, b: float, xy: np.ndarray, yaw: float, y_mid: float) -> None:
    """Shrubs along a..b whose backs touch the host (their centres `width / 2` off its face)."""
    rng = lay.rng
    mid = 0.5 * (a + b)
    p = _host_to_scene(xy, yaw, mid, y_mid)
    x = a + 0.5 * pl.width
    while x < b - 0.3 * pl.width:
        r = 0.5 * pl.width * rng.uniform(0.8, 1.1)
        q = p + _host_to_scene(np.zeros(2), yaw, x - mid, 0.0)
        iid = lay.reg.new("shrub_row", (m.VEGETATION,), position=(q[0], q[1], lay.z(q)))
        bld = PrimitiveBuilder()
        bld.ellipsoid((0.0, 0.0, 0.45 * pl.height), (r, r, 0.55 * pl.height), m.VEGETATION, iid,
                      m.foliage(rng, dense=True))
        lay.put(bld, q, yaw)
        lay.bushes.append((q, r))
        x += 2 * r + rng.uniform(-0.3, 0.6)  # some overlap, some gaps


def add_trunk_shrub(lay: Layout, b: PrimitiveBuilder, rt: float, pos: np.ndarray) -> None:
    """A shrub grown against a trunk of radius `rt` (its own instance): the trunk stands in its
    edge, so bark and leaves meet."""
    rng = lay.rng
    r = rng.uniform(0.35, 0.8)
    ang = rng.uniform(0, 2 * np.pi)
    d = rt + r * rng.uniform(0.3, 0.9)
    iid = lay.reg.new("trunk_shrub", (m.VEGETATION,), position=tuple(pos))
    b.ellipsoid((d * np.cos(ang), d * np.sin(ang), 0.7 * r), (r, r * rng.uniform(0.8, 1.2), r * rng.uniform(0.8, 1.2)),
                m.VEGETATION, iid, m.foliage(rng, dense=True))


def add_rack(lay: Layout, xy: np.ndarray, yaw: float, n: int, spacing: float) -> None:
    """A bike rack of `n` hoops `spacing` m apart along local x (the bikes stand along local y,
    each against a hoop)."""
    iid = lay.reg.new("rack", (m.OTHER_OBJECT,), position=(xy[0], xy[1], lay.z(xy)))
    steel = Material(refl=lay.rng.uniform(0.25, 0.5), drop=0.03)
    bld = PrimitiveBuilder()
    for k in range(n):
        x = k * spacing + 0.08  # beside the bike's frame: it touches the wheels and the bar
        for y in (-0.35, 0.35):
            bld.capsule((x, y, 0.0), (x, y, 0.75), 0.025, m.OTHER_OBJECT, iid, steel)
        bld.capsule((x, -0.35, 0.75), (x, 0.35, 0.75), 0.025, m.OTHER_OBJECT, iid, steel)
    lay.put(bld, xy, yaw)


LEAN_WALL_P = 0.35  # walls and fences with people leaning on them
BIKES_AT_WALL_P = 0.15


def lean_on_walls(lay: Layout, walls: list[Facade]) -> None:
    """People leaning back on walls and fences (feet 0.25-0.4 m out, shoulders on the wall) and
    bicycles leaning on walls (handlebar against it)."""
    rng = lay.rng
    for f in walls:
        d = f.ends[1] - f.ends[0]
        length = float(np.linalg.norm(d))
        if length < 2.0:
            continue
        along = d / length
        if rng.random() < LEAN_WALL_P:
            for _ in range(int(rng.integers(1, 4))):
                feet = f.ends[0] + rng.uniform(0.5, length - 0.5) * along + rng.uniform(0.25, 0.4) * f.normal
                _leaning_person(lay, feet, f.normal, rng)
        if f.wall and rng.random() < BIKES_AT_WALL_P:
            x = rng.uniform(0.5, max(0.6, length - 4.0))
            for _ in range(int(rng.integers(1, 4))):
                _leaning_bike(lay, f.ends[0] + x * along + rng.uniform(0.42, 0.5) * f.normal, along, f.normal, rng)
                x += rng.uniform(0.6, 1.2)


def _leaning_person(lay: Layout, feet: np.ndarray, normal: np.ndarray, rng: np.random.Generator) -> None:
    # the wall's own occupancy cells reach up to 0.35 m out of it: test the ground in front of the feet
    if not lay.free(lay.disc(feet + 0.3 * normal, 0.15), min_clear=None):
        return
    lay.mark(lay.disc(feet, 0.3))
    iid = lay.reg.new("person_leaning", (m.PERSON,), position=(feet[0], feet[1], lay.z(feet)))
    bld = PrimitiveBuilder()
    m.add_person(bld, lay.style.draw_person(rng), m.PERSON, iid, rng.uniform(0, 2 * np.pi), 0.0)
    yaw = float(np.arctan2(normal[1], normal[0]))  # facing away from the wall
    lay.put(bld, feet, yaw, rot=rot_z(yaw) @ rot_y(-np.deg2rad(rng.uniform(5.0, 11.0))))


def _leaning_bike(lay: Layout, xy: np.ndarray, along: np.ndarray, normal: np.ndarray, rng) -> None:
    if not lay.free(lay.rect(xy + 0.2 * normal, float(np.arctan2(along[1], along[0])), 0.5, 0.1), min_clear=None):
        return
    lay.mark(lay.rect(xy, float(np.arctan2(along[1], along[0])), 0.6, 0.2))
    iid = lay.reg.new("bicycle_leaning", (m.BICYCLE,), position=(xy[0], xy[1], lay.z(xy)))
    bld = PrimitiveBuilder()
    m.add_bicycle(bld, m.BICYCLE, iid, Material(refl=rng.uniform(0.2, 0.6)))
    yaw = float(np.arctan2(along[1], along[0]))
    # roll the top over towards the wall: rot_x(a > 0) tips local +z towards local -y
    wall_side = -1.0 if (np.array([-np.sin(yaw), np.cos(yaw)]) @ normal) > 0 else 1.0  # local y of the wall
    lay.put(bld, xy, yaw, rot=rot_z(yaw) @ rot_x(-wall_side * np.deg2rad(rng.uniform(8.0, 14.0))))
