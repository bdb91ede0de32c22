"""Who moves on the campus: traffic in both lanes, cyclists, pedestrians and crossers
(people, and cyclists coming off the sidewalk, cross at zebra crossings).

Counts scale with the loop length, with `crowd` (1 = the default campus; the learning
experiments use a busier one, so that a route holds many distinct people, cyclists and cars) and,
for cyclists, with `cyclists` on top; a few actors are always put near the ego vehicle's start
(an oncoming car, a car about to overtake, one pulling away ahead, two cyclists, walkers and
people on the zebra crossing ahead), so that even a short run sees every moving class.
"""

from __future__ import annotations

import numpy as np

from research.simulation import models as m
from research.simulation.actors import Actor, LanePath, PolylinePath, lane_offsets_smoothed
from research.simulation.ground import GroundModel
from research.simulation.layout import Layout, Registry, RoadSpec
from research.simulation.route import EgoProfile, Route
from research.simulation.shapes import PrimitiveBuilder
from research.simulation.style import STYLES, CampusStyle


def populate_actors(
    rng: np.random.Generator,
    route: Route,
    ground: GroundModel,
    road: RoadSpec,
    ego: EgoProfile,
    lay: Layout,
    reg: Registry,
    crossings: np.ndarray,
    crowd: float = 1.0,
    cyclists: float = 1.0,
    style: CampusStyle | None = None,
    extra: np.random.Generator | None = None,
) -> list[Actor]:
    """The moving actors. `extra`: the varied styles' own random stream (car, cyclist and group
    kinds), so that their layout and traffic are those of the plain style."""
    style = style or STYLES["a"]
    varied = style.variety and extra is not None
    actors: list[Actor] = []

    def vehicle() -> str:
        if not varied:
            return "bike"
        return str(extra.choice(["bike", "child", "cargo", "scooter"], p=list(style.cyclist_kind_p)))

    def companions() -> tuple:
        if not varied or extra.random() >= style.group_share:
            return ()
        side = 1 if extra.random() < 0.5 else -1
        sides = (side,) if extra.random() < 0.7 else (side, -side)  # a pair, or three abreast
        return tuple((style.draw_person(extra), float(extra.uniform(-0.25, 0.25)), sd * float(extra.uniform(0.55, 0.75)),
                      float(extra.uniform(0, 2 * np.pi))) for sd in sides)

    length = route.length
    s_ego = ego.s0

    def car(s0: float, v: float) -> None:
        shape = style.draw_car(rng, extra=extra if varied else None)
        iid = reg.new("car", (m.MOVING_CAR,), moving=True, dark=shape.dark)
        if v < 0:
            path = LanePath(route, s0, v, road.lane)
        else:
            path = LanePath(route, s0, v, -road.lane, ego=ego, overtake_lat=road.lane)
        b = PrimitiveBuilder()
        m.add_car(b, shape, m.MOVING_CAR, iid)
        actors.append(Actor(iid, "car", m.MOVING_CAR, path, shape, abs(v), model=b.build()))

    def cyclist(s0: float, v: float) -> None:
        lat = (road.road_half - 0.45) * (1 if v < 0 else -1)
        iid = reg.new("cyclist", (m.MOVING_BICYCLIST,), moving=True)
        path = LanePath(route, s0, v, lat)
        actors.append(
            Actor(
                iid,
                "cyclist",
                m.MOVING_BICYCLIST,
                path,
                style.draw_person(rng),
                abs(v),
                rng.uniform(0, 2 * np.pi),
                rng.uniform(0.15, 0.6),
                vehicle=vehicle(),
            )
        )

    follow = {1: lane_offsets_smoothed(ground.low_left), -1: lane_offsets_smoothed(ground.low_right)}

    def walker(s0: float, side: int) -> None:
        v = rng.uniform(0.9, 1.6) * (1 if rng.random() < 0.5 else -1)
        off = rng.uniform(0.8, max(0.9, road.sidewalk(side) - 0.35))
        iid = reg.new("person", (m.MOVING_PERSON,), moving=True)
        path = LanePath(route, s0, v, side * off, follow=follow[side])
        actors.append(
            Actor(iid, "person", m.MOVING_PERSON, path, style.draw_person(rng), abs(v), rng.uniform(0, 2 * np.pi),
                  companions=companions())
        )

    def polyline_walker(points: np.ndarray, t0: float, v: float | None = None, group: bool = True) -> None:
        v = v or rng.uniform(0.9, 1.5)
        iid = reg.new("person", (m.MOVING_PERSON,), moving=True)
        actors.append(
            Actor(
                iid,
                "person",
                m.MOVING_PERSON,
                PolylinePath(points, v, t0),
                style.draw_person(rng),
                v,
                rng.uniform(0, 2 * np.pi),
                companions=companions() if group else (),
            )
        )

    # 1. Traffic near the start, then spread over the loop.
    car(s_ego + rng.uniform(35.0, 60.0), -rng.uniform(6.0, 9.0))
    car(s_ego - rng.uniform(15.0, 28.0), rng.uniform(7.5, 9.5))
    car(s_ego + rng.uniform(20.0, 35.0), rng.uniform(6.5, 8.5))
    for _ in range(int(length / 60 * crowd)):
        car(rng.uniform(0, length), -rng.uniform(5.5, 9.5))
    for _ in range(int(length / 160 * crowd)):
        car(rng.uniform(0, length), rng.uniform(6.5, 9.5))
    # 2. Cyclists by the curb, both directions.
    cyclist(s_ego + rng.uniform(30.0, 50.0), -rng.uniform(3.5, 6.0))
    cyclist(s_ego + rng.uniform(12.0, 20.0), rng.uniform(3.0, 4.0))
    for _ in range(int(length / 90 * crowd * cyclists)):
        cyclist(rng.uniform(0, length), rng.uniform(3.5, 6.5) * (1 if rng.random() < 0.5 else -1))
    # 3. Pedestrians on the sidewalks.
    for k in range(4):
        walker(s_ego + rng.uniform(-10.0, 45.0), 1 if k % 2 else -1)
    for _ in range(int(length / 16 * crowd)):
        walker(rng.uniform(0, length), 1 if rng.random() < 0.5 else -1)
    # 4. People walking close to walls and hedges (foreground / background confusion).
    for f in lay.facades:
        if rng.random() < 0.5:
            off = rng.uniform(0.35, 0.7)
            polyline_walker(f.ends + off * f.normal[None], rng.uniform(0, 60), group=False)
    for h in lay.hedges:
        if np.linalg.norm(h.ends[1] - h.ends[0]) > 5.0 and rng.random() < 0.4:
            off = rng.uniform(0.25, 0.5)
            polyline_walker(h.ends + off * h.normal[None], rng.uniform(0, 60), group=False)
    # 5. Crossers at zebra crossings, timed to be on the road shortly before the ego arrives.
    for sc in crossings:
        t_arrive = ego.time_at(float(sc), length)
        for _ in range(int(rng.integers(1, 4))):
            side = 1 if rng.random() < 0.5 else -1
            lat_a = side * (road.road_half + rng.uniform(0.8, 1.6))
            lat_b = -side * (road.road_half + rng.uniform(0.8, 1.6))
            sc_k = sc + rng.uniform(-1.2, 1.2)
            before, after = rng.uniform(8.0, 20.0), rng.uniform(8.0, 20.0)
            d = 1 if rng.random() < 0.5 else -1
            pts = np.stack(
                [
                    route.offset(sc_k - d * before, lat_a),
                    route.offset(sc_k, lat_a),
                    route.offset(sc_k, lat_b),
                    route.offset(sc_k + d * after, lat_b),
                ]
            )
            v = rng.uniform(1.0, 1.6)
            d_mid = before + 0.5 * abs(lat_b - lat_a)
            t_mid = t_arrive - rng.uniform(3.5, 7.0)
            polyline_walker(pts, t_mid - d_mid / v, v)
        if rng.random() < 0.5:
            # A cyclist riding along the far sidewalk, across the zebra and on along the other one.
            side = 1 if rng.random() < 0.5 else -1
            lat_a, lat_b = side * (road.road_half + 1.0), -side * (road.road_half + 1.0)
            before, after = rng.uniform(20.0, 35.0), rng.uniform(20.0, 35.0)
            d = 1 if rng.random() < 0.5 else -1
            pts = np.stack(
                [
                    route.offset(sc - d * before, lat_a),
                    route.offset(sc - d * 1.5, lat_a),
                    route.offset(sc + d * 1.5, lat_b),
                    route.offset(sc + d * after, lat_b),
                ]
            )
            v = rng.uniform(3.0, 4.5)
            t_mid = t_arrive - rng.uniform(3.0, 6.0)
            d_mid = float(np.linalg.norm(pts[1] - pts[0]) + 0.5 * np.linalg.norm(pts[2] - pts[1]))
            iid = reg.new("cyclist", (m.MOVING_BICYCLIST,), moving=True)
            path = PolylinePath(pts, v, t_mid - d_mid / v)
            actors.append(
                Actor(
                    iid,
                    "cyclist",
                    m.MOVING_BICYCLIST,
                    path,
                    style.draw_person(rng),
                    v,
                    rng.uniform(0, 2 * np.pi),
                    rng.uniform(0.15, 0.6),
                    vehicle=vehicle(),
                )
            )
    return actors
