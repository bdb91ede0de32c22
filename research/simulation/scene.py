"""The synthetic campus: route, ground, static objects, actors and the ego vehicle, per seed.

`build_scene(seed)` draws everything from `seed` alone (different seeds give different
loops, layouts and traffic); `Scene.sensor_pose(t)` and `Scene.primitives_near(t, ...)` are
what one simulated frame needs. Coordinates are in the scene frame (metres, z up); the
written sequence's world frame is the sensor frame of its first frame.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from research.simulation.actors import Actor, actor_poses, ground_frame
from research.simulation.ground import GroundModel, lateral_grid, make_waves
from research.simulation.layout import (
    InstanceInfo,
    Layout,
    Registry,
    RoadSpec,
    low_widths,
    plan_stretches,
)
from research.simulation.planting import populate, static_primitives
from research.simulation.population import populate_actors
from research.simulation.route import EgoProfile, Route, make_ego_profile, make_route
from research.simulation.shapes import PrimitiveSet, concat
from research.simulation.style import get_style

SENSOR_HEIGHT = 1.8  # metres above the road, on the ego vehicle's roof


@dataclass(frozen=True)
class Scene:
    """One seed's campus.

    static: (P,) primitives that never move; static_tree: KD-tree over their centres (xy);
    static_radius: (P,) their bounding radii. actors: moving things (and nothing else).
    instances: instance id -> InstanceInfo for every static object and actor.
    """

    seed: int
    route: Route
    ground: GroundModel
    road: RoadSpec
    ego: EgoProfile
    static: PrimitiveSet
    static_tree: cKDTree
    static_radius: np.ndarray
    actors: tuple[Actor, ...]
    instances: dict[int, InstanceInfo]
    crossings: np.ndarray
    crowd: float = 1.0  # moving-actor density factor the scene was drawn with
    cyclists: float = 1.0  # extra factor on the number of cyclists
    style: str = "a"  # campus style (research.simulation.style)

    def sensor_pose(self, t: float) -> np.ndarray:
        """(4, 4) T_scene_lidar at time t: the ego in its lane, tilted with the road."""
        s = float(self.ego.s_at(t))
        xy = self.route.offset(s, self.ego.lat)
        yaw = float(self.route.yaw(s))
        rot = ground_frame(self.ground, xy, yaw)
        z = float(self.ground.height(xy[None])[0])
        pose = np.eye(4)
        pose[:3, :3] = rot
        pose[:3, 3] = np.array([xy[0], xy[1], z]) + rot @ np.array([0.0, 0.0, SENSOR_HEIGHT])
        return pose

    def primitives_near(self, t: float, origin: np.ndarray, max_range: float) -> PrimitiveSet:
        """Static primitives and actors at time t that may reach within `max_range` of `origin`."""
        r_max = float(self.static_radius.max()) if len(self.static_radius) else 0.0
        idx = np.sort(
            np.asarray(self.static_tree.query_ball_point(origin[:2], max_range + r_max), dtype=np.int64)
        )
        d = np.linalg.norm(self.static.center[idx, :2] - origin[None, :2], axis=1)
        idx = idx[d - self.static_radius[idx] <= max_range]
        sets = [self.static.take(idx)]
        xy, yaw = actor_poses(self.actors, t)
        near = np.flatnonzero(np.linalg.norm(xy - origin[None, :2], axis=1) <= max_range + 4.0)
        if len(near):
            z = self.ground.height(xy[near])
            normal = self.ground.normal(xy[near])
            for j, i in enumerate(near.tolist()):
                sets.append(self.actors[i].posed(t, xy[i], float(yaw[i]), float(z[j]), normal[j]))
        return concat(sets)

    def instance_primitives(self, instance: int, t: float) -> PrimitiveSet:
        """The primitives of one instance at time t (scene frame)."""
        for a in self.actors:
            if a.instance == instance:
                return a.primitives(t, self.ground)
        return self.static.take(np.flatnonzero(self.static.instance == instance))


def build_scene(seed: int, crowd: float = 1.0, cyclists: float = 1.0, style: str = "a") -> Scene:
    """Draw the whole campus from `seed`; `crowd` scales the number of moving actors, `cyclists`
    that of cyclists on top of it; `style` names the distributions objects are drawn from
    (`research.simulation.style`)."""
    campus = get_style(style)
    # spawn(7)'s first five children are spawn(5)'s: the plain styles' draws do not change
    streams = [np.random.default_rng(s) for s in np.random.SeedSequence(int(seed)).spawn(7)]
    rng_route, rng_road, rng_layout, rng_actors, rng_ego, extra_layout, extra_actors = streams
    # 1. The loop and the ego vehicle's drive along it.
    route = make_route(rng_route)
    road = RoadSpec(
        road_half=rng_road.uniform(3.25, 3.75),
        sidewalk_left=rng_road.uniform(1.8, 3.2),
        sidewalk_right=rng_road.uniform(1.8, 3.2),
        curb=rng_road.uniform(0.1, 0.15),
    )
    ego = make_ego_profile(rng_ego, route, road.lane)
    # 2. Street cross-section along the loop: bays, lots, zebra crossings.
    stretches = plan_stretches(rng_layout, route, ego.s0)
    left, right = low_widths(route, road, stretches, rng_layout)
    runs = route.straight_runs(margin=15.0)
    picks = [float(rng_layout.uniform(a, b)) for a, b in runs if rng_layout.random() < 0.5]
    crossings = np.asarray(
        sorted([float(np.mod(ego.s0 + rng_layout.uniform(18.0, 26.0), route.length)), *picks])
    )
    for sc in crossings:  # no bays across a crossing
        idx = route.index(np.arange(sc - 6.0, sc + 6.0, 0.25))
        left[idx] = road.road_half
        right[idx] = road.road_half
    origin, lat, sidx = lateral_grid(route)
    ground = GroundModel(
        waves=make_waves(rng_road),
        origin=origin,
        lat=lat,
        sidx=sidx,
        low_left=left,
        low_right=right,
        crossings=crossings,
        road_half=road.road_half,
        sidewalk_left=road.sidewalk_left,
        sidewalk_right=road.sidewalk_right,
        curb=road.curb,
        route_length=route.length,
    )
    # 3. Static objects, then 4. everything that moves.
    reg = Registry()
    lay = Layout(rng_layout, route, ground, road, reg, campus, extra_layout)
    populate(lay, stretches, crossings)
    static = static_primitives(lay)
    actors = populate_actors(
        rng_actors, route, ground, road, ego, lay, reg, crossings, crowd, cyclists, campus, extra_actors
    )
    return Scene(
        seed=int(seed),
        route=route,
        ground=ground,
        road=road,
        ego=ego,
        static=static,
        static_tree=cKDTree(static.center[:, :2]),
        static_radius=static.bounding_radius(),
        actors=tuple(actors),
        instances=dict(reg.infos),
        crossings=crossings,
        crowd=float(crowd),
        cyclists=float(cyclists),
        style=campus.name,
    )
