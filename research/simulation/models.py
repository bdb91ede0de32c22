"""Object models built from a few analytic primitives, in the object's own frame.

Object frame: x forward, y left, z up, origin on the ground under the object's centre.
Every function adds primitives to a `PrimitiveBuilder` with the given semantic and instance
ids; size, shape and material parameters come from the caller's random draws, so that no
two instances look the same.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from research.simulation.shapes import Material, PrimitiveBuilder, rot_x, rot_y

# SemanticKITTI ids used by the simulator.
CAR, BICYCLE, PERSON, BICYCLIST = 10, 11, 30, 31
MOVING_CAR, MOVING_BICYCLIST, MOVING_PERSON = 252, 253, 254
BUILDING, FENCE, VEGETATION, TRUNK = 50, 51, 70, 71
POLE, TRAFFIC_SIGN, OTHER_OBJECT = 80, 81, 99

# Car windows: most rays pass into the cabin (and return from the seats, or from beyond the car);
# the glass itself returns weakly, and seldom at oblique incidence.
GLASS = Material(refl=0.03, drop=0.05, spec=0.6, porosity=0.25)
INTERIOR = Material(refl=0.06, drop=0.1)  # seats and dashboard behind the car's windows
RUBBER = Material(refl=0.05, drop=0.15, spec=0.3)
PLASTIC = Material(refl=0.15, drop=0.02)
RETRO = Material(refl=0.9)
METAL = Material(refl=0.4, drop=0.02, spec=0.2)
SKIN = Material(refl=0.35)
WHEEL_SPOKED = Material(refl=0.1, drop=0.1, porosity=0.55)

_WHEEL_ROT = rot_x(np.pi / 2)  # cylinder axis (local z) along the object's y axis


# ------------------------------------------------------------------------------- cars


@dataclass(frozen=True)
class CarShape:
    """Dimensions (m) and finish of one car."""

    length: float
    width: float
    height: float
    body_height: float  # top of the lower body above its underside
    cabin_length: float
    cabin_offset: float  # cabin centre along x, relative to the body centre
    clearance: float
    wheel_radius: float
    paint: Material
    dark: bool
    kind: str
    roof_box: bool = False  # a roof box on the cabin (varied styles)

    @property
    def overall_length(self) -> float:
        """Bumper to bumper, plates included (`add_car`)."""
        return self.length + 2 * BUMPER_REACH

    @property
    def overall_width(self) -> float:
        """Mirror to mirror (`add_car`)."""
        return self.width + 2 * MIRROR_REACH


BUMPER_REACH = 0.115  # the plates stand this far beyond the body
MIRROR_REACH = 0.2


CAR_KINDS = {
    # kind: (length, width, height, body_height, cabin share, cabin offset share)
    "small": ((3.5, 3.9), (1.6, 1.72), (1.40, 1.55), (0.50, 0.60), (0.55, 0.65), (-0.05, 0.0)),
    "sedan": ((4.4, 4.9), (1.75, 1.88), (1.40, 1.52), (0.52, 0.62), (0.45, 0.55), (-0.08, -0.02)),
    "suv": ((4.4, 4.9), (1.82, 1.98), (1.62, 1.80), (0.68, 0.80), (0.55, 0.65), (-0.06, 0.0)),
    "van": ((4.8, 5.4), (1.90, 2.05), (1.90, 2.30), (0.80, 1.00), (0.78, 0.84), (-0.06, -0.04)),
    # the varied styles' kinds (`EXTRA_CAR_KINDS`): a cabin reaching the rear, a cab with an open
    # bed behind it, a short cab with a tall cargo box behind it
    "hatch": ((3.9, 4.3), (1.70, 1.80), (1.45, 1.60), (0.52, 0.62), (0.62, 0.72), (-0.13, -0.09)),
    "pickup": ((5.0, 5.6), (1.85, 2.0), (1.75, 1.90), (0.75, 0.90), (0.30, 0.36), (0.12, 0.17)),
    "boxvan": ((5.6, 7.0), (2.0, 2.25), (2.6, 3.2), (0.80, 0.95), (0.20, 0.24), (0.36, 0.40)),
}
EXTRA_CAR_KINDS = ("hatch", "pickup", "boxvan")


CAR_KIND_P = (0.25, 0.4, 0.2, 0.15)  # small, sedan, suv, van
DARK_SHARE = 0.3  # cars with dark paint (they lose oblique returns and break up)


def draw_car(
    rng: np.random.Generator, dark_share: float = DARK_SHARE, kind: str | None = None,
    kind_p: tuple[float, ...] = CAR_KIND_P,
) -> CarShape:
    """A random car: small, sedan, SUV or van (`kind_p`); `dark_share` of them have dark paint."""
    if kind is None:
        kind = str(rng.choice(list(CAR_KINDS)[: len(kind_p)], p=list(kind_p)))
    lo_hi = CAR_KINDS[kind]
    length, width, height, body_h, cab_share, cab_off = (rng.uniform(*r) for r in lo_hi)
    dark = bool(rng.random() < dark_share)
    # reflectivities tuned to SemanticKITTI's car remission (a quarter of it near 0, median 0.08)
    if dark:
        paint = Material(refl=rng.uniform(0.005, 0.03), drop=0.05, spec=rng.uniform(0.8, 0.92))
    else:
        paint = Material(refl=rng.uniform(0.2, 0.75), drop=0.01, spec=rng.uniform(0.1, 0.35))
    return CarShape(
        length=length,
        width=width,
        height=height,
        body_height=body_h,
        cabin_length=cab_share * length,
        cabin_offset=cab_off * length,
        clearance=rng.uniform(0.16, 0.24),
        wheel_radius=rng.uniform(0.29, 0.36),
        paint=paint,
        dark=dark,
        kind=kind,
    )


def add_car(b: PrimitiveBuilder, car: CarShape, semantic: int, instance: int) -> None:
    """Body, glass cabin with seats inside, roof, four wheels, bumpers, plates and mirrors (14
    primitives); a pickup's bed walls, a box van's cargo box, a roof box."""
    half_l, half_w = car.length / 2, car.width / 2
    z0 = car.clearance
    _car_extras(b, car, semantic, instance)
    b.box(
        (0, 0, z0 + car.body_height / 2), (half_l, half_w, car.body_height / 2), semantic, instance, car.paint
    )
    cab_h = car.height - z0 - car.body_height
    cab_top = car.height
    b.box(
        (car.cabin_offset, 0, z0 + car.body_height + cab_h / 2 - 0.04),
        (car.cabin_length / 2, half_w - 0.08, cab_h / 2 - 0.04),
        semantic,
        instance,
        GLASS,
    )
    b.box(
        (car.cabin_offset, 0, z0 + car.body_height + 0.3 * cab_h),
        (0.4 * car.cabin_length, half_w - 0.3, 0.3 * cab_h),
        semantic,
        instance,
        INTERIOR,
    )
    b.box(
        (car.cabin_offset, 0, cab_top - 0.04),
        (car.cabin_length / 2 * 0.9, half_w - 0.1, 0.04),
        semantic,
        instance,
        car.paint,
    )
    rw = car.wheel_radius
    for sx in (-1, 1):
        for sy in (-1, 1):
            b.cylinder(
                (sx * (half_l - 0.75), sy * (half_w - 0.09), rw),
                rw,
                0.11,
                semantic,
                instance,
                RUBBER,
                _WHEEL_ROT,
            )
    for sx in (-1, 1):
        b.box((sx * (half_l + 0.04), 0, z0 + 0.22), (0.06, half_w - 0.05, 0.12), semantic, instance, PLASTIC)
        b.box((sx * (half_l + 0.105), 0, z0 + 0.28), (0.01, 0.26, 0.06), semantic, instance, RETRO)
    x_mirror = car.cabin_offset + car.cabin_length / 2 - 0.15
    for sy in (-1, 1):
        b.box(
            (x_mirror, sy * (half_w + 0.1), z0 + car.body_height + 0.12),
            (0.06, 0.1, 0.06),
            semantic,
            instance,
            car.paint,
        )


def _car_extras(b: PrimitiveBuilder, car: CarShape, semantic: int, instance: int) -> None:
    half_l, half_w = car.length / 2, car.width / 2
    top = car.clearance + car.body_height
    cab_rear = car.cabin_offset - car.cabin_length / 2
    if car.kind == "pickup":  # the bed: side walls and tailgate above the body behind the cab
        length = cab_rear + half_l - 0.1
        xc = -half_l + length / 2
        for sy in (-1, 1):
            b.box((xc, sy * (half_w - 0.04), top + 0.22), (length / 2, 0.04, 0.22), semantic, instance, car.paint)
        b.box((-half_l + 0.04, 0, top + 0.22), (0.04, half_w - 0.04, 0.22), semantic, instance, car.paint)
    elif car.kind == "boxvan":  # a cargo box from behind the cab to the rear, up to the full height
        length = cab_rear + half_l - 0.15
        box_mat = Material(refl=min(0.8, car.paint.refl + 0.2), drop=0.01, spec=0.1)
        b.box((-half_l + length / 2, 0, (top + car.height) / 2), (length / 2, half_w, (car.height - top) / 2),
              semantic, instance, box_mat)
    if car.roof_box:
        b.box((car.cabin_offset - 0.1, 0, car.height + 0.2), (min(0.9, 0.4 * car.cabin_length), 0.4, 0.18),
              semantic, instance, PLASTIC)


# ------------------------------------------------------------------------------ people


@dataclass(frozen=True)
class PersonShape:
    height: float
    build: float  # width factor
    top: Material
    bottom: Material
    backpack: bool
    carry: str = ""  # "" | "bag" (shoulder bag / suitcase at the side) | "umbrella" | "coat" (long coat)


CHILD_SHARE = 0.12
CLOTH_REFL = (0.06, 0.6)  # remission range of clothes
CARRY_P = (0.62, 0.16, 0.08, 0.14)  # nothing, bag, umbrella, coat


def draw_person(
    rng: np.random.Generator, child_share: float = CHILD_SHARE, cloth_refl: tuple[float, float] = CLOTH_REFL,
    carry_p: tuple[float, ...] = CARRY_P,
) -> PersonShape:
    """Adults and teenagers of 1.45-1.98 m and children of 1.0-1.45 m (`child_share`), slim to
    broad builds; clothes from dark to bright (`cloth_refl`); some carry a backpack, a bag or an
    umbrella, or wear a long coat that hides the legs (`carry_p`)."""
    if rng.random() < child_share:
        height = float(rng.uniform(1.0, 1.45))
    else:
        height = float(np.clip(rng.normal(1.72, 0.1), 1.45, 1.98))

    def cloth() -> Material:
        refl = rng.uniform(*cloth_refl)
        return Material(refl=refl, drop=0.03, spec=0.5 if refl < 0.1 else 0.1)

    build = float(rng.uniform(0.8, 1.35))
    top, bottom, backpack = cloth(), cloth(), bool(rng.random() < 0.25)
    carry = str(rng.choice(["", "bag", "umbrella", "coat"], p=list(carry_p)))
    return PersonShape(height, build, top, bottom, backpack, carry)


def add_person(
    b: PrimitiveBuilder, p: PersonShape, semantic: int, instance: int, gait: float, swing: float
) -> None:
    """Legs, torso, arms and head; `gait` is the stride phase (rad), `swing` its amplitude (rad)."""
    h = p.height
    wf = p.build
    r_leg = 0.07 * wf
    hip = 0.52 * h
    leg = hip - r_leg
    for side, ph in ((1, 0.0), (-1, np.pi)):
        a = swing * np.sin(gait + ph)
        y = side * 0.09 * wf
        b.capsule(
            (0, y, hip), (leg * np.sin(a), y, hip - leg * np.cos(a)), r_leg, semantic, instance, p.bottom
        )
    b.ellipsoid((0, 0, hip + 0.165 * h), (0.12 * wf, 0.19 * wf, 0.175 * h), semantic, instance, p.top)
    shoulder = 0.8 * h
    arm = 0.33 * h
    for side, ph in ((1, np.pi), (-1, 0.0)):
        a = 0.8 * swing * np.sin(gait + ph)
        y = side * 0.21 * wf
        hand = (arm * np.sin(a), y + side * 0.04, shoulder - arm * np.cos(a))
        b.capsule((0, y, shoulder), hand, 0.045 * wf, semantic, instance, p.top)
    s = h / 1.75
    b.ellipsoid((0.01, 0, 0.935 * h), (0.095 * s, 0.08 * s, 0.115 * s), semantic, instance, SKIN)
    if p.backpack:
        b.box((-0.2 * wf, 0, 0.66 * h), (0.09, 0.15 * wf, 0.2), semantic, instance, PLASTIC)
    if p.carry == "bag":  # a bag at the right hip (or a suitcase at hand height)
        b.box((0.0, -0.3 * wf, 0.45 * h), (0.17, 0.07, 0.16), semantic, instance, PLASTIC)
    elif p.carry == "umbrella":  # open canopy above the head, shaft in the right hand
        b.capsule((0.05, -0.2 * wf, 0.55 * h), (0.05, -0.1, 1.12 * h), 0.012, semantic, instance, METAL)
        b.ellipsoid((0.05, -0.1, 1.14 * h), (0.5, 0.5, 0.12), semantic, instance, PLASTIC)
    elif p.carry == "coat":  # a long coat: a cone-like skirt from the hips to the knees
        b.ellipsoid((0, 0, 0.36 * h), (0.16 * wf, 0.23 * wf, 0.2 * h), semantic, instance, p.top)


# ---------------------------------------------------------------------------- bicycles


def add_bicycle(b: PrimitiveBuilder, semantic: int, instance: int, frame_mat: Material) -> None:
    """Two spoked wheels, frame tubes and handlebar (8 primitives); wheelbase ~1.05 m."""
    rw = 0.34
    for x in (-0.52, 0.52):
        b.cylinder((x, 0, rw), rw, 0.025, semantic, instance, WHEEL_SPOKED, _WHEEL_ROT)
    rear, bb, seat = (-0.52, 0, rw), (-0.05, 0, 0.3), (-0.2, 0, 0.85)
    head_top, head_low, front = (0.4, 0, 0.84), (0.43, 0, 0.68), (0.52, 0, rw)
    for p0, p1 in ((rear, bb), (bb, seat), (seat, head_top), (bb, head_low), (head_low, front)):
        b.capsule(p0, p1, 0.022, semantic, instance, frame_mat)
    b.capsule((0.38, -0.27, 0.98), (0.38, 0.27, 0.98), 0.02, semantic, instance, frame_mat)


def add_rider(
    b: PrimitiveBuilder, p: PersonShape, semantic: int, instance: int, crank: float, lean: float
) -> None:
    """A rider on `add_bicycle`'s bike: pedalling legs (`crank` rad), torso leaning `lean` rad."""
    s = p.height / 1.75
    hip = np.array([-0.2, 0.0, 0.93])
    torso_len = 0.52 * s
    axis = np.array([np.sin(lean), 0.0, np.cos(lean)])
    b.ellipsoid(
        hip + 0.5 * torso_len * axis,
        (0.11 * p.build, 0.18 * p.build, 0.3 * s),
        semantic,
        instance,
        p.top,
        rot_y(lean),
    )
    shoulder = hip + 0.92 * torso_len * axis
    b.ellipsoid(shoulder + (0.08, 0, 0.17 * s), (0.095 * s, 0.08 * s, 0.115 * s), semantic, instance, SKIN)
    for side in (1, -1):
        b.capsule(shoulder + (0, side * 0.19, 0), (0.38, side * 0.24, 0.98), 0.04, semantic, instance, p.top)
    thigh, shin = 0.245 * p.height, 0.25 * p.height
    bb = np.array([-0.05, 0.0, 0.3])
    for side, ph in ((1, 0.0), (-1, np.pi)):
        y = side * 0.12
        foot = bb + 0.17 * np.array([np.cos(crank + ph), 0.0, np.sin(crank + ph)])
        h0 = hip + (0, y, 0)
        f0 = foot + (0, y, 0)
        d = f0 - h0
        dist = min(np.linalg.norm(d), thigh + shin - 1e-3)
        # Knee from the two-link chain, bent forward.
        a = (thigh**2 - shin**2 + dist**2) / (2 * dist)
        hgt = np.sqrt(max(thigh**2 - a**2, 0.0))
        u = d / np.linalg.norm(d)
        perp = np.array([-u[2], 0.0, u[0]])
        if perp[0] < 0:
            perp = -perp
        knee = h0 + a * u + hgt * perp
        b.capsule(h0, knee, 0.065 * p.build, semantic, instance, p.bottom)
        b.capsule(knee, f0, 0.05 * p.build, semantic, instance, p.bottom)


# --------------------------------------------------------------------------- vegetation


def add_trunk(b: PrimitiveBuilder, radius: float, top: float, instance: int, bark: Material) -> None:
    b.cylinder((0, 0, 0.5 * (top - 0.3)), radius, 0.5 * (top + 0.3), TRUNK, instance, bark)


def foliage(rng: np.random.Generator, dense: bool = False, climber: bool = False) -> Material:
    """Leaves: dense (hedges, shrubs, conifers), open (crowns) or a climber's thin layer on a wall.
    Depth, porosity and grain are tuned so that range scatter along rows and beams matches
    SemanticKITTI's vegetation (docs/simulator.md)."""
    if climber:
        return Material(refl=rng.uniform(0.3, 0.5), drop=0.04, porosity=rng.uniform(0.02, 0.08),
                        depth=rng.uniform(0.03, 0.06), noise=0.01, grain=rng.uniform(0.06, 0.12))
    if dense:  # trimmed or dense leaves: returns from the outer few centimetres
        return Material(refl=rng.uniform(0.3, 0.5), drop=0.04, porosity=rng.uniform(0.04, 0.1),
                        depth=rng.uniform(0.05, 0.1), noise=0.005, grain=rng.uniform(0.08, 0.16))
    # a crown: rays reach deep between the leaves (neighbouring returns decimetres apart)
    return Material(refl=rng.uniform(0.3, 0.5), drop=0.05, porosity=rng.uniform(0.15, 0.3),
                    depth=rng.uniform(0.35, 0.7), noise=0.005, grain=rng.uniform(0.06, 0.12))


def add_canopy(
    b: PrimitiveBuilder,
    rng: np.random.Generator,
    base: float,
    radius: float,
    height: float,
    instance: int,
    leaves: Material,
) -> float:
    """A crown of 1-4 ellipsoid lobes above `base`; returns the crown centre height."""
    cz = base + height / 2
    b.ellipsoid(
        (0, 0, cz), (radius, radius * rng.uniform(0.85, 1.15), height / 2), VEGETATION, instance, leaves
    )
    for _ in range(int(rng.integers(0, 4))):
        ang = rng.uniform(0, 2 * np.pi)
        off = rng.uniform(0.3, 0.6) * radius
        r = radius * rng.uniform(0.45, 0.7)
        c = (off * np.cos(ang), off * np.sin(ang), cz + rng.uniform(-0.25, 0.3) * height / 2)
        b.ellipsoid(c, (r, r, r * rng.uniform(0.7, 1.1)), VEGETATION, instance, leaves)
    return cz


BUSH_KINDS = ("round", "columnar", "spreading", "sparse")
BUSH_P = (0.5, 0.18, 0.17, 0.15)


def add_bush(
    b: PrimitiveBuilder, rng: np.random.Generator, size: float, instance: int, kind_p: tuple[float, ...] = BUSH_P
) -> None:
    """A shrub about `size` metres across, sunk a little into the ground; one of BUSH_KINDS:

    round      1-3 overlapping dense ellipsoids (the common garden shrub);
    columnar   a tall narrow shrub (cypress, yew) of 1.3-3 m, 0.5-0.9 m across: the height and
               width of a person or of a tree trunk with its lower crown;
    spreading  2-4 low wide lobes, 0.4-0.9 m high (ground cover, low hedging plants);
    sparse     round but open foliage (few leaves, winter): fewer, scattered returns.
    """
    kind = str(rng.choice(BUSH_KINDS, p=list(kind_p)))
    if kind == "columnar":
        leaves = foliage(rng, dense=True)
        h = rng.uniform(1.3, 3.0)
        r = rng.uniform(0.25, 0.45)
        b.ellipsoid((0, 0, 0.5 * h - 0.05), (r, r * rng.uniform(0.8, 1.1), 0.5 * h), VEGETATION, instance, leaves)
        return
    if kind == "spreading":
        leaves = foliage(rng, dense=True)
        for _ in range(int(rng.integers(2, 5))):
            r = size / 2 * rng.uniform(0.4, 0.8)
            rz = rng.uniform(0.2, 0.45)
            off = size * rng.uniform(0.0, 0.4)
            ang = rng.uniform(0, 2 * np.pi)
            b.ellipsoid((off * np.cos(ang), off * np.sin(ang), 0.6 * rz), (r, r * rng.uniform(0.7, 1.3), rz),
                        VEGETATION, instance, leaves)
        return
    leaves = foliage(rng, dense=kind == "round")
    for k in range(int(rng.integers(1, 4))):
        r = size / 2 * rng.uniform(0.6, 1.0)
        rz = r * rng.uniform(0.6, 1.0)
        off = 0.0 if k == 0 else size * rng.uniform(0.2, 0.45)
        ang = rng.uniform(0, 2 * np.pi)
        b.ellipsoid(
            (off * np.cos(ang), off * np.sin(ang), 0.75 * rz),
            (r, r * rng.uniform(0.8, 1.2), rz),
            VEGETATION,
            instance,
            leaves,
        )


def add_hedge(
    b: PrimitiveBuilder, rng: np.random.Generator, length: float, width: float, height: float, instance: int
) -> None:
    """A trimmed hedge along x, sunk 0.1 m into the ground."""
    b.box(
        (0, 0, height / 2 - 0.1),
        (length / 2, width / 2, height / 2 + 0.1),
        VEGETATION,
        instance,
        foliage(rng, dense=True),
    )


# ----------------------------------------------------------------------------- buildings


@dataclass(frozen=True)
class FacadeShape:
    """A front wall with a grid of recessed windows (m): bays of `period` along the wall, each with
    a window `window` wide; floors `floor` high, windows from `sill` above each floor's base, `pane`
    high; window reveals `recess` deep. Returns from the openings come from the frames and blinds at
    the back of the reveal; a 7-pixel row window across a reveal's edge sees the step, which gives
    real walls their tail of rough-looking pixels (more of them farther away, where a 7-pixel
    window spans more wall)."""

    period: float
    window: float
    floor: float
    sill: float
    pane: float
    recess: float


def draw_facade(rng: np.random.Generator) -> FacadeShape:
    period = rng.uniform(2.2, 3.6)
    floor = rng.uniform(3.0, 3.6)
    return FacadeShape(
        period=period,
        window=period * rng.uniform(0.4, 0.65),
        floor=floor,
        sill=rng.uniform(0.8, 1.0),
        pane=floor * rng.uniform(0.4, 0.55),
        recess=rng.uniform(0.12, 0.3),
    )


def add_facade(
    b: PrimitiveBuilder, f: FacadeShape, x0: float, x1: float, bottom: float, top: float, instance: int,
    wall: Material,
) -> None:
    """The outer `f.recess` m of a front wall at local y in [-recess, 0], x in [x0, x1]: piers between
    the windows (full height) and, per floor, the wall below and above the windows. The block behind
    it ends at y = -recess."""
    r = f.recess
    n = max(1, int((x1 - x0) // f.period))
    edge = 0.5 * (x1 - x0 - n * f.period)  # the wall left at both ends
    gaps = [(x0 + edge + k * f.period + 0.5 * (f.period - f.window), x0 + edge + k * f.period
             + 0.5 * (f.period + f.window)) for k in range(n)]
    piers = [x0, *(x for g in gaps for x in g), x1]
    for a, c in zip(piers[::2], piers[1::2], strict=True):
        b.box(((a + c) / 2, -r / 2, (bottom + top) / 2), ((c - a) / 2, r / 2, (top - bottom) / 2), BUILDING,
              instance, wall)
    z = 0.0
    spans = []
    while z + f.sill + f.pane < top - 0.3:
        spans.append((z + f.sill, z + f.sill + f.pane))
        z += f.floor
    bands = [bottom, *(v for s in spans for v in s), top]
    xa, xb = gaps[0][0], gaps[-1][1]
    for lo, hi in zip(bands[::2], bands[1::2], strict=True):
        b.box(((xa + xb) / 2, -r / 2, (lo + hi) / 2), ((xb - xa) / 2, r / 2, (hi - lo) / 2), BUILDING, instance,
              wall)
