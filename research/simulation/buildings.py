"""Buildings of the campus layout: a front the street sees, wings and towers, a recessed entrance
under an overhang, facades with windows (`models.add_facade`), planting against the wall.
`Layout` (research/simulation/layout.py) takes these methods from `Buildings`."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from research.simulation import contacts as ct
from research.simulation import models as m
from research.simulation.shapes import Material, PrimitiveBuilder


@dataclass
class Facade:
    """A building front a pedestrian can walk along: end points (2, 2) and outward normal (2,)."""

    ends: np.ndarray
    normal: np.ndarray
    wall: bool = True  # a building's wall (False: a fence)


class Buildings:
    """The building methods of `Layout` (they use its grid, registry, ground and style)."""

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
