"""The campus plan: every stretch filled by its type (avenue, frontage, hedges, bays, lot, open),
then the background buildings and vegetation, street furniture and standing people, and the
static primitives of the whole layout."""

from __future__ import annotations

import numpy as np

from research.simulation import contacts as ct
from research.simulation import furniture as fu
from research.simulation import models as m
from research.simulation.layout import (
    BAY_WIDTH,
    GARDEN_FENCE_P,
    Layout,
    Stretch,
)
from research.simulation.shapes import PrimitiveBuilder, PrimitiveSet, concat


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
            fu.add_sitting_person(b, st.draw_person(x), m.PERSON, iid)
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
                fu.add_hydrant(b, iid)
            elif what == "postbox":
                fu.add_postbox(b, x, iid)
            elif what == "cabinet":
                fu.add_cabinet(b, x, iid)
            elif what == "planter":
                fu.add_planter(b, x, iid, lay.reg.new("bush", (m.VEGETATION,), position=pos))
            else:
                fu.add_statue(b, x, iid)
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
                fu.add_kiosk(b, x, lay.reg.new("kiosk", (m.BUILDING,), position=(p[0], p[1], lay.z(p))), hx, hy)
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
