"""Street furniture (lamps, signs, cones, bins, benches, bollards, fences) and the kinds the varied
campus styles add (people sitting, scooters, cargo boxes, hydrants, post boxes, cabinets,
planters, statues, kiosks, varied bushes). The materials and SemanticKITTI ids are `models`'."""

from __future__ import annotations

import numpy as np

from research.simulation.models import (
    _WHEEL_ROT,
    BUILDING,
    FENCE,
    METAL,
    OTHER_OBJECT,
    POLE,
    RETRO,
    RUBBER,
    SKIN,
    TRAFFIC_SIGN,
    VEGETATION,
    WHEEL_SPOKED,
    PersonShape,
    add_person,
    foliage,
)
from research.simulation.shapes import Material, PrimitiveBuilder, rot_x

# --------------------------------------------------------------------- street furniture


def add_lamp(b: PrimitiveBuilder, rng: np.random.Generator, instance: int) -> None:
    """A lamp post leaning its head over +y (towards the road)."""
    h = rng.uniform(4.5, 8.0)
    r = rng.uniform(0.06, 0.12)
    b.cylinder((0, 0, h / 2 - 0.2), r, h / 2 + 0.2, POLE, instance, METAL)
    arm = rng.uniform(0.8, 1.6)
    b.capsule((0, 0, h - 0.1), (0, arm, h + 0.15), 0.04, POLE, instance, METAL)
    b.box((0, arm, h + 0.08), (0.18, 0.3, 0.06), POLE, instance, Material(refl=0.3))


def add_sign(b: PrimitiveBuilder, rng: np.random.Generator, instance: int) -> None:
    """A sign post with a plate facing +y (towards the road); the plate is traffic-sign."""
    h = rng.uniform(2.1, 2.8)
    b.cylinder((0, 0, h / 2 - 0.15), 0.035, h / 2 + 0.15, POLE, instance, METAL)
    if rng.random() < 0.5:
        b.cylinder(
            (0, 0.05, h + 0.15), rng.uniform(0.3, 0.4), 0.01, TRAFFIC_SIGN, instance, RETRO, rot_x(np.pi / 2)
        )
    else:
        s = rng.uniform(0.3, 0.45)
        b.box((0, 0.05, h + s * 0.8), (s, 0.01, s * 0.8), TRAFFIC_SIGN, instance, RETRO)


def add_cone(b: PrimitiveBuilder, instance: int) -> None:
    """A traffic cone: base plate and three stacked, narrowing drums with a reflective band."""
    orange = Material(refl=0.5)
    b.box((0, 0, 0.015), (0.19, 0.19, 0.015), OTHER_OBJECT, instance, orange)
    b.cylinder((0, 0, 0.16), 0.15, 0.13, OTHER_OBJECT, instance, orange)
    b.cylinder((0, 0, 0.39), 0.105, 0.1, OTHER_OBJECT, instance, RETRO)
    b.cylinder((0, 0, 0.59), 0.065, 0.1, OTHER_OBJECT, instance, orange)


def add_bin(b: PrimitiveBuilder, rng: np.random.Generator, instance: int) -> None:
    h = rng.uniform(0.8, 1.1)
    b.cylinder(
        (0, 0, h / 2),
        rng.uniform(0.22, 0.35),
        h / 2,
        OTHER_OBJECT,
        instance,
        Material(refl=rng.uniform(0.1, 0.45)),
    )


def add_bench(b: PrimitiveBuilder, rng: np.random.Generator, instance: int) -> None:
    """A bench along x, its back on the -y side."""
    half = rng.uniform(0.8, 1.1)
    wood = Material(refl=rng.uniform(0.2, 0.4))
    b.box((0, 0, 0.45), (half, 0.22, 0.03), OTHER_OBJECT, instance, wood)
    b.box((0, -0.22, 0.75), (half, 0.03, 0.18), OTHER_OBJECT, instance, wood)
    for sx in (-1, 1):
        b.box((sx * (half - 0.1), 0, 0.21), (0.03, 0.2, 0.21), OTHER_OBJECT, instance, METAL)


def add_bollard(b: PrimitiveBuilder, instance: int) -> None:
    b.cylinder((0, 0, 0.45), 0.1, 0.45, OTHER_OBJECT, instance, Material(refl=0.35))


def add_fence(b: PrimitiveBuilder, rng: np.random.Generator, length: float, instance: int) -> float:
    """A fence along x: a solid wall or a see-through mesh on posts; returns its height."""
    h = rng.uniform(1.0, 1.9)
    if rng.random() < 0.5:  # boards, slats or panels: centimetres to decimetres of relief
        b.box(
            (0, 0, h / 2 - 0.1),
            (length / 2, 0.04, h / 2 + 0.1),
            FENCE,
            instance,
            Material(refl=rng.uniform(0.2, 0.55), depth=rng.uniform(0.08, 0.2), grain=rng.uniform(0.03, 0.06)),
        )
    else:  # a mesh or railing: most rays pass through its gaps
        b.box((0, 0, h / 2), (length / 2, 0.02, h / 2), FENCE, instance,
              Material(refl=rng.uniform(0.2, 0.55), porosity=0.6, depth=rng.uniform(0.06, 0.15), grain=0.05))
        n = max(2, int(length / 2.5) + 1)
        for x in np.linspace(-length / 2, length / 2, n):
            b.cylinder((x, 0, h / 2), 0.03, h / 2, FENCE, instance, METAL)
    return h


# ------------------------------------------------------------- the varied styles' kinds


def add_sitting_person(b: PrimitiveBuilder, p: PersonShape, semantic: int, instance: int, seat: float = 0.48) -> None:
    """A person sitting facing +x on a seat `seat` m high: thighs forward, shins down, upright torso."""
    h, wf = p.height, p.build
    hip_z = seat + 0.07 * wf
    thigh = 0.245 * h  # the shins hang from the knees to the ground
    for side in (1, -1):
        y = side * 0.1 * wf
        knee = (thigh, y, hip_z + 0.02)
        b.capsule((0.0, y, hip_z), knee, 0.07 * wf, semantic, instance, p.bottom)
        b.capsule(knee, (thigh + 0.05, y, 0.06), 0.055 * wf, semantic, instance, p.bottom)
    torso_h = 0.175 * h
    b.ellipsoid((-0.03, 0, hip_z + 0.05 + torso_h), (0.12 * wf, 0.19 * wf, torso_h), semantic, instance, p.top)
    shoulder = hip_z + 0.05 + 1.75 * torso_h
    for side in (1, -1):
        b.capsule((0, side * 0.21 * wf, shoulder), (0.25, side * 0.15 * wf, hip_z + 0.12), 0.045 * wf, semantic,
                  instance, p.top)
    s = h / 1.75
    b.ellipsoid((0.0, 0, shoulder + 0.17 * s), (0.095 * s, 0.08 * s, 0.115 * s), semantic, instance, SKIN)


def add_scooter(b: PrimitiveBuilder, p: PersonShape, semantic: int, instance: int, deck: Material) -> None:
    """An e-scooter rider: small wheels, a deck, a stem with a handlebar, a person standing upright."""
    for x in (-0.42, 0.42):
        b.cylinder((x, 0, 0.1), 0.1, 0.025, semantic, instance, RUBBER, _WHEEL_ROT)
    b.box((0.0, 0, 0.14), (0.38, 0.08, 0.025), semantic, instance, deck)
    b.capsule((0.42, 0, 0.12), (0.36, 0, 1.05), 0.02, semantic, instance, METAL)
    b.capsule((0.36, -0.25, 1.05), (0.36, 0.25, 1.05), 0.018, semantic, instance, METAL)
    rider = PrimitiveBuilder()
    add_person(rider, p, semantic, instance, 0.3, 0.05)
    rider.shift(-0.08, 0.0, 0.16)  # standing on the deck, a little back
    b.extend(rider)


def add_cargo_box(b: PrimitiveBuilder, semantic: int, instance: int, mat: Material) -> None:
    """The load box in front of a cargo bike's handlebar (on `add_bicycle`'s frame)."""
    b.box((0.95, 0, 0.5), (0.38, 0.32, 0.25), semantic, instance, mat)
    b.cylinder((1.3, 0, 0.2), 0.2, 0.025, semantic, instance, WHEEL_SPOKED, _WHEEL_ROT)


def add_hydrant(b: PrimitiveBuilder, instance: int) -> None:
    red = Material(refl=0.35)
    b.cylinder((0, 0, 0.35), 0.11, 0.35, OTHER_OBJECT, instance, red)
    b.ellipsoid((0, 0, 0.72), (0.12, 0.12, 0.08), OTHER_OBJECT, instance, red)
    b.cylinder((0, 0, 0.45), 0.05, 0.2, OTHER_OBJECT, instance, red, _WHEEL_ROT)


def add_postbox(b: PrimitiveBuilder, rng: np.random.Generator, instance: int) -> None:
    """A post box on a post or a pillar box: 1.1-1.6 m, the size of a child."""
    mat = Material(refl=rng.uniform(0.2, 0.5))
    if rng.random() < 0.5:
        b.cylinder((0, 0, 0.55), 0.04, 0.55, OTHER_OBJECT, instance, METAL)
        b.box((0, 0, 1.2), (0.2, 0.18, 0.25), OTHER_OBJECT, instance, mat)
    else:
        h = rng.uniform(1.3, 1.6)
        b.cylinder((0, 0, h / 2), rng.uniform(0.22, 0.3), h / 2, OTHER_OBJECT, instance, mat)


def add_cabinet(b: PrimitiveBuilder, rng: np.random.Generator, instance: int) -> None:
    """A utility cabinet: a grey box 1.0-1.6 m high, 0.6-1.4 m wide."""
    h, w = rng.uniform(1.0, 1.6), rng.uniform(0.3, 0.7)
    b.box((0, 0, h / 2), (w, rng.uniform(0.2, 0.35), h / 2), OTHER_OBJECT, instance,
          Material(refl=rng.uniform(0.25, 0.55), spec=0.1))


def add_planter(b: PrimitiveBuilder, rng: np.random.Generator, instance: int, plant: int) -> None:
    """A concrete planter (other object) with a shrub in it (vegetation, instance `plant`)."""
    half, h = rng.uniform(0.4, 0.9), rng.uniform(0.4, 0.7)
    b.box((0, 0, h / 2), (half, half * rng.uniform(0.6, 1.0), h / 2), OTHER_OBJECT, instance,
          Material(refl=rng.uniform(0.3, 0.55)))
    b.ellipsoid((0, 0, h + 0.25), (0.8 * half, 0.7 * half, rng.uniform(0.25, 0.6)), VEGETATION, plant,
                foliage(rng, dense=True))


def add_statue(b: PrimitiveBuilder, rng: np.random.Generator, instance: int) -> None:
    """A statue on a plinth: a figure of stone or bronze, a person's shape on a block."""
    plinth = rng.uniform(0.5, 1.4)
    stone = Material(refl=rng.uniform(0.1, 0.5), spec=0.2)
    b.box((0, 0, plinth / 2), (0.45, 0.45, plinth / 2), OTHER_OBJECT, instance, stone)
    h = rng.uniform(1.4, 2.2)
    fig = PrimitiveBuilder()
    add_person(fig, PersonShape(h, rng.uniform(0.9, 1.4), stone, stone, False), OTHER_OBJECT, instance,
               rng.uniform(0, 2 * np.pi), rng.uniform(0.0, 0.3))
    fig.shift(0.0, 0.0, plinth)
    b.extend(fig)


def add_kiosk(b: PrimitiveBuilder, rng: np.random.Generator, instance: int, hx: float, hy: float) -> None:
    """A kiosk or shed (building) of half extents (hx, hy), 2.3-3.2 m high, its roof overhanging
    the front (+y) by 0.9 m and the sides by 0.2 m."""
    h = rng.uniform(2.3, 3.2)
    wall = Material(refl=rng.uniform(0.15, 0.6), drop=0.01, spec=0.05)
    b.box((0, 0, h / 2 - 0.1), (hx, hy, h / 2 + 0.1), BUILDING, instance, wall)
    b.box((0, 0.45, h + 0.05), (hx + 0.2, hy + 0.45, 0.06), BUILDING, instance, wall)


def add_varied_bush(b: PrimitiveBuilder, rng: np.random.Generator, size: float, instance: int) -> None:
    """The varied styles' shrubs: a pruned box (0.5-1.3 m, flat faces, like a cabinet or a car's
    flank) or a standard (a ball of leaves, 0.5-1.1 m across, on a 0.9-1.6 m stem: a person's or
    a young tree's height)."""
    leaves = foliage(rng, dense=True)
    if rng.random() < 0.5:
        half = 0.5 * float(np.clip(size, 0.6, 1.6))
        h = rng.uniform(0.5, 1.3)
        b.box((0, 0, h / 2 - 0.05), (half, half * rng.uniform(0.6, 1.0), h / 2), VEGETATION, instance, leaves)
        return
    stem = rng.uniform(0.9, 1.6)
    r = rng.uniform(0.25, 0.55)
    b.cylinder((0, 0, stem / 2), rng.uniform(0.025, 0.05), stem / 2, VEGETATION, instance,
               Material(refl=rng.uniform(0.2, 0.35)))
    b.ellipsoid((0, 0, stem + 0.8 * r), (r, r, r * rng.uniform(0.8, 1.1)), VEGETATION, instance, leaves)
