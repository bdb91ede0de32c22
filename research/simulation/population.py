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
    kinds), so that their layout and traffic are those of the plain style.

    The steps draw from `rng` in a fixed order: changing the order changes every seed's campus.
    """
    pop = _Population(rng, route, ground, road, ego, reg, style or STYLES["a"], extra)
    pop.traffic(crowd)
    pop.curb_cyclists(crowd, cyclists)
    pop.sidewalk_walkers(crowd)
    pop.wall_walkers(lay)
    for sc in crossings:
        pop.crossers(sc)
    return pop.actors


class _Population:
    """The actors drawn so far, and one method per kind of actor and per step of `populate_actors`."""

    def __init__(
        self,
        rng: np.random.Generator,
        route: Route,
        ground: GroundModel,
        road: RoadSpec,
        ego: EgoProfile,
        reg: Registry,
        style: CampusStyle,
        extra: np.random.Generator | None,
    ) -> None:
        self.rng, self.route, self.road, self.ego, self.reg, self.style = rng, route, road, ego, reg, style
        self.extra = extra
        self.varied = style.variety and extra is not None
        self.follow = {1: lane_offsets_smoothed(ground.low_left), -1: lane_offsets_smoothed(ground.low_right)}
        self.actors: list[Actor] = []

    # --- drawing one actor

    def vehicle(self) -> str:
        if not self.varied:
            return "bike"
        return str(self.extra.choice(["bike", "child", "cargo", "scooter"], p=list(self.style.cyclist_kind_p)))

    def companions(self) -> tuple:
        extra = self.extra
        if not self.varied or extra.random() >= self.style.group_share:
            return ()
        side = 1 if extra.random() < 0.5 else -1
        sides = (side,) if extra.random() < 0.7 else (side, -side)  # a pair, or three abreast
        return tuple((self.style.draw_person(extra), float(extra.uniform(-0.25, 0.25)),
                      sd * float(extra.uniform(0.55, 0.75)), float(extra.uniform(0, 2 * np.pi))) for sd in sides)

    def car(self, s0: float, v: float) -> None:
        shape = self.style.draw_car(self.rng, extra=self.extra if self.varied else None)
        iid = self.reg.new("car", (m.MOVING_CAR,), moving=True, dark=shape.dark)
        if v < 0:
            path = LanePath(self.route, s0, v, self.road.lane)
        else:
            path = LanePath(self.route, s0, v, -self.road.lane, ego=self.ego, overtake_lat=self.road.lane)
        b = PrimitiveBuilder()
        m.add_car(b, shape, m.MOVING_CAR, iid)
        self.actors.append(Actor(iid, "car", m.MOVING_CAR, path, shape, abs(v), model=b.build()))

    def cyclist(self, path: LanePath | PolylinePath, v: float) -> None:
        rng = self.rng
        iid = self.reg.new("cyclist", (m.MOVING_BICYCLIST,), moving=True)
        self.actors.append(Actor(iid, "cyclist", m.MOVING_BICYCLIST, path, self.style.draw_person(rng), abs(v),
                                 rng.uniform(0, 2 * np.pi), rng.uniform(0.15, 0.6), vehicle=self.vehicle()))

    def lane_cyclist(self, s0: float, v: float) -> None:
        lat = (self.road.road_half - 0.45) * (1 if v < 0 else -1)
        self.cyclist(LanePath(self.route, s0, v, lat), v)

    def walker(self, s0: float, side: int) -> None:
        rng = self.rng
        v = rng.uniform(0.9, 1.6) * (1 if rng.random() < 0.5 else -1)
        off = rng.uniform(0.8, max(0.9, self.road.sidewalk(side) - 0.35))
        iid = self.reg.new("person", (m.MOVING_PERSON,), moving=True)
        path = LanePath(self.route, s0, v, side * off, follow=self.follow[side])
        self.actors.append(Actor(iid, "person", m.MOVING_PERSON, path, self.style.draw_person(rng), abs(v),
                                 rng.uniform(0, 2 * np.pi), companions=self.companions()))

    def polyline_walker(self, points: np.ndarray, t0: float, v: float | None = None, group: bool = True) -> None:
        rng = self.rng
        v = v or rng.uniform(0.9, 1.5)
        iid = self.reg.new("person", (m.MOVING_PERSON,), moving=True)
        self.actors.append(Actor(iid, "person", m.MOVING_PERSON, PolylinePath(points, v, t0),
                                 self.style.draw_person(rng), v, rng.uniform(0, 2 * np.pi),
                                 companions=self.companions() if group else ()))

    # --- the steps

    def traffic(self, crowd: float) -> None:
        """Traffic near the start, then spread over the loop."""
        rng, s_ego, length = self.rng, self.ego.s0, self.route.length
        self.car(s_ego + rng.uniform(35.0, 60.0), -rng.uniform(6.0, 9.0))
        self.car(s_ego - rng.uniform(15.0, 28.0), rng.uniform(7.5, 9.5))
        self.car(s_ego + rng.uniform(20.0, 35.0), rng.uniform(6.5, 8.5))
        for _ in range(int(length / 60 * crowd)):
            self.car(rng.uniform(0, length), -rng.uniform(5.5, 9.5))
        for _ in range(int(length / 160 * crowd)):
            self.car(rng.uniform(0, length), rng.uniform(6.5, 9.5))

    def curb_cyclists(self, crowd: float, cyclists: float) -> None:
        """Cyclists by the curb, both directions."""
        rng, s_ego, length = self.rng, self.ego.s0, self.route.length
        self.lane_cyclist(s_ego + rng.uniform(30.0, 50.0), -rng.uniform(3.5, 6.0))
        self.lane_cyclist(s_ego + rng.uniform(12.0, 20.0), rng.uniform(3.0, 4.0))
        for _ in range(int(length / 90 * crowd * cyclists)):
            self.lane_cyclist(rng.uniform(0, length), rng.uniform(3.5, 6.5) * (1 if rng.random() < 0.5 else -1))

    def sidewalk_walkers(self, crowd: float) -> None:
        """Pedestrians on the sidewalks."""
        rng, s_ego, length = self.rng, self.ego.s0, self.route.length
        for k in range(4):
            self.walker(s_ego + rng.uniform(-10.0, 45.0), 1 if k % 2 else -1)
        for _ in range(int(length / 16 * crowd)):
            self.walker(rng.uniform(0, length), 1 if rng.random() < 0.5 else -1)

    def wall_walkers(self, lay: Layout) -> None:
        """People walking close to walls and hedges (foreground / background confusion)."""
        rng = self.rng
        for f in lay.facades:
            if rng.random() < 0.5:
                off = rng.uniform(0.35, 0.7)
                self.polyline_walker(f.ends + off * f.normal[None], rng.uniform(0, 60), group=False)
        for h in lay.hedges:
            if np.linalg.norm(h.ends[1] - h.ends[0]) > 5.0 and rng.random() < 0.4:
                off = rng.uniform(0.25, 0.5)
                self.polyline_walker(h.ends + off * h.normal[None], rng.uniform(0, 60), group=False)

    def crossers(self, sc: float) -> None:
        """Crossers at the zebra crossing at arc length `sc`, timed to be on the road shortly
        before the ego arrives: one to three people and, half the time, a cyclist."""
        rng, road, route = self.rng, self.road, self.route
        t_arrive = self.ego.time_at(float(sc), route.length)
        for _ in range(int(rng.integers(1, 4))):
            side = 1 if rng.random() < 0.5 else -1
            lat_a = side * (road.road_half + rng.uniform(0.8, 1.6))
            lat_b = -side * (road.road_half + rng.uniform(0.8, 1.6))
            sc_k = sc + rng.uniform(-1.2, 1.2)
            before, after = rng.uniform(8.0, 20.0), rng.uniform(8.0, 20.0)
            d = 1 if rng.random() < 0.5 else -1
            pts = np.stack([route.offset(sc_k - d * before, lat_a), route.offset(sc_k, lat_a),
                            route.offset(sc_k, lat_b), route.offset(sc_k + d * after, lat_b)])
            v = rng.uniform(1.0, 1.6)
            d_mid = before + 0.5 * abs(lat_b - lat_a)
            t_mid = t_arrive - rng.uniform(3.5, 7.0)
            self.polyline_walker(pts, t_mid - d_mid / v, v)
        if rng.random() < 0.5:
            self.crossing_cyclist(sc, t_arrive)

    def crossing_cyclist(self, sc: float, t_arrive: float) -> None:
        """A cyclist riding along the far sidewalk, across the zebra and on along the other one."""
        rng, road, route = self.rng, self.road, self.route
        side = 1 if rng.random() < 0.5 else -1
        lat_a, lat_b = side * (road.road_half + 1.0), -side * (road.road_half + 1.0)
        before, after = rng.uniform(20.0, 35.0), rng.uniform(20.0, 35.0)
        d = 1 if rng.random() < 0.5 else -1
        pts = np.stack([route.offset(sc - d * before, lat_a), route.offset(sc - d * 1.5, lat_a),
                        route.offset(sc + d * 1.5, lat_b), route.offset(sc + d * after, lat_b)])
        v = rng.uniform(3.0, 4.5)
        t_mid = t_arrive - rng.uniform(3.0, 6.0)
        d_mid = float(np.linalg.norm(pts[1] - pts[0]) + 0.5 * np.linalg.norm(pts[2] - pts[1]))
        self.cyclist(PolylinePath(pts, v, t_mid - d_mid / v), v)
