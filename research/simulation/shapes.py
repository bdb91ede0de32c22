"""Analytic primitives the simulated world is built from, and their signed distance.

Every primitive has a local frame (`rot` maps local to scene axes, `center` is the local
origin in the scene) and a `size` (3,) whose meaning depends on the kind:

    BOX        half extents (hx, hy, hz)
    CYLINDER   (r, r, half height) around the local z axis
    ELLIPSOID  radii (a, b, c)
    CAPSULE    (r, r, half length) of a segment along the local z axis, radius r

Each primitive also carries its labels (SemanticKITTI semantic id, instance id) and a surface
material (see `Material`), which the ray caster and the return model read.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

BOX, CYLINDER, ELLIPSOID, CAPSULE = 0, 1, 2, 3
N_MATERIAL = 7  # columns of a material row (see `Material`)


@dataclass(frozen=True)
class Material:
    """How a surface answers a laser pulse.

    refl:     reflectivity in [0, 1] (remission at normal incidence).
    drop:     probability that a return is lost regardless of geometry.
    spec:     specular strength in [0, 1]: returns are lost at oblique incidence (dark paint, glass).
    porosity: probability that a ray passes through the primitive (foliage gaps, car glass).
    depth:    mean penetration depth in metres (foliage), or for a closed surface (bark) the
              largest relief below it; 0 for smooth surfaces.
    noise:    extra range noise sigma in metres on top of the sensor's.
    grain:    texture cell size in metres (leaf clusters, bark plates): the depth a ray reaches
              and, for foliage, whether it passes are drawn once per cell of the primitive's local
              frame, so neighbouring rays that meet one cell agree and the texture stays put from
              frame to frame, as real foliage does; 0 draws them per ray and frame instead.
    """

    refl: float
    drop: float = 0.0
    spec: float = 0.0
    porosity: float = 0.0
    depth: float = 0.0
    noise: float = 0.0
    grain: float = 0.0


@dataclass(frozen=True)
class PrimitiveSet:
    """P primitives in the scene frame.

    kind:     (P,) int8 BOX | CYLINDER | ELLIPSOID | CAPSULE.
    center:   (P, 3) float64 local origin in the scene frame.
    rot:      (P, 3, 3) float64 scene-from-local rotation.
    size:     (P, 3) float64, see the module docstring.
    semantic: (P,) uint16 SemanticKITTI id; instance: (P,) uint16 instance id >= 1.
    material: (P, 7) float32 columns refl, drop, spec, porosity, depth, noise, grain.
    """

    kind: np.ndarray
    center: np.ndarray
    rot: np.ndarray
    size: np.ndarray
    semantic: np.ndarray
    instance: np.ndarray
    material: np.ndarray

    def __post_init__(self) -> None:
        p = len(self.kind)
        assert self.center.shape == (p, 3) and self.rot.shape == (p, 3, 3) and self.size.shape == (p, 3)
        assert self.semantic.shape == (p,) and self.instance.shape == (p,)
        assert self.material.shape == (p, N_MATERIAL) and self.material.dtype == np.float32

    def __len__(self) -> int:
        return len(self.kind)

    def take(self, index: np.ndarray) -> PrimitiveSet:
        """The primitives at `index` (int array or bool mask)."""
        return PrimitiveSet(
            self.kind[index],
            self.center[index],
            self.rot[index],
            self.size[index],
            self.semantic[index],
            self.instance[index],
            self.material[index],
        )

    def transformed(self, rot: np.ndarray, t: np.ndarray) -> PrimitiveSet:
        """The set moved rigidly: p -> rot @ p + t."""
        return PrimitiveSet(
            self.kind,
            self.center @ rot.T + t[None],
            np.einsum("ij,pjk->pik", rot, self.rot),
            self.size,
            self.semantic,
            self.instance,
            self.material,
        )

    def bound_half_extents(self) -> np.ndarray:
        """(P, 3) half extents of each primitive's bounding box in its local frame."""
        ext = self.size.copy()
        cap = self.kind == CAPSULE
        ext[cap, 2] += self.size[cap, 0]
        return ext

    def corners(self) -> np.ndarray:
        """(P, 8, 3) corners of each primitive's local bounding box, in the scene frame."""
        signs = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], float)
        local = signs[None] * self.bound_half_extents()[:, None, :]  # (P, 8, 3)
        return np.einsum("pij,pkj->pki", self.rot, local) + self.center[:, None, :]

    def bounding_radius(self) -> np.ndarray:
        """(P,) radius of the sphere around `center` that holds the primitive."""
        return np.linalg.norm(self.bound_half_extents(), axis=1)


def empty_set() -> PrimitiveSet:
    return PrimitiveSet(
        np.zeros(0, np.int8),
        np.zeros((0, 3)),
        np.zeros((0, 3, 3)),
        np.zeros((0, 3)),
        np.zeros(0, np.uint16),
        np.zeros(0, np.uint16),
        np.zeros((0, N_MATERIAL), np.float32),
    )


def concat(sets: list[PrimitiveSet]) -> PrimitiveSet:
    """One set holding the primitives of `sets` in order."""
    sets = [s for s in sets if len(s)]
    if not sets:
        return empty_set()
    return PrimitiveSet(*(np.concatenate([getattr(s, f) for s in sets]) for f in _FIELDS))


_FIELDS = ("kind", "center", "rot", "size", "semantic", "instance", "material")


def rot_z(yaw: float) -> np.ndarray:
    """(3, 3) rotation about z by `yaw` radians."""
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def rot_y(pitch: float) -> np.ndarray:
    """(3, 3) rotation about y by `pitch` radians (positive tips +x down towards -z)."""
    c, s = np.cos(pitch), np.sin(pitch)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def rot_x(roll: float) -> np.ndarray:
    c, s = np.cos(roll), np.sin(roll)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def frame_from_axis(axis) -> np.ndarray:
    """(3, 3) rotation whose local z axis is the unit vector along `axis` (3,)."""
    ax, ay, az = (float(v) for v in axis)
    n = math.sqrt(ax * ax + ay * ay + az * az)
    ax, ay, az = ax / n, ay / n, az / n
    # x = normalise(helper x z), helper = e_x unless z is close to it (then e_y).
    if abs(ax) < 0.9:
        xx, xy, xz = 0.0, -az, ay
    else:
        xx, xy, xz = az, 0.0, -ax
    m = math.sqrt(xx * xx + xy * xy + xz * xz)
    xx, xy, xz = xx / m, xy / m, xz / m
    yx, yy, yz = ay * xz - az * xy, az * xx - ax * xz, ax * xy - ay * xx
    return np.array([[xx, yx, ax], [xy, yy, ay], [xz, yz, az]])


class PrimitiveBuilder:
    """Collects primitives in an object's local frame, then places them in the scene.

    Coordinates given to `box`, `cylinder`, ... are in the builder's frame; `build(pose_rot,
    pose_t)` maps them to the scene with `p_scene = pose_rot @ p + pose_t`.
    """

    def __init__(self) -> None:
        self._kind: list[int] = []
        self._center: list[tuple[float, float, float]] = []
        self._rot: list[np.ndarray | None] = []
        self._size: list[tuple[float, float, float]] = []
        self._sem: list[int] = []
        self._inst: list[int] = []
        self._mat: list[Material] = []

    def __len__(self) -> int:
        return len(self._kind)

    def _add(self, kind: int, center, rot, size, semantic: int, instance: int, mat: Material) -> None:
        self._kind.append(kind)
        self._center.append((float(center[0]), float(center[1]), float(center[2])))
        self._rot.append(rot)
        self._size.append((float(size[0]), float(size[1]), float(size[2])))
        self._sem.append(semantic)
        self._inst.append(instance)
        self._mat.append(mat)

    def box(self, center, half, semantic: int, instance: int, mat: Material, rot=None) -> None:
        self._add(BOX, center, rot, half, semantic, instance, mat)

    def cylinder(
        self, center, radius: float, half_height: float, semantic: int, instance: int, mat: Material, rot=None
    ) -> None:
        self._add(CYLINDER, center, rot, (radius, radius, half_height), semantic, instance, mat)

    def ellipsoid(self, center, radii, semantic: int, instance: int, mat: Material, rot=None) -> None:
        self._add(ELLIPSOID, center, rot, radii, semantic, instance, mat)

    def capsule(self, p0, p1, radius: float, semantic: int, instance: int, mat: Material) -> None:
        """A capsule around the segment p0-p1 (builder frame)."""
        x0, y0, z0 = (float(v) for v in p0)
        x1, y1, z1 = (float(v) for v in p1)
        axis = (x1 - x0, y1 - y0, z1 - z0)
        length = math.sqrt(axis[0] ** 2 + axis[1] ** 2 + axis[2] ** 2)
        rot = frame_from_axis(axis) if length > 1e-9 else None
        centre = (0.5 * (x0 + x1), 0.5 * (y0 + y1), 0.5 * (z0 + z1))
        self._add(CAPSULE, centre, rot, (radius, radius, 0.5 * length), semantic, instance, mat)

    def scale(self, factor: float) -> None:
        """Scale everything added so far about the builder's origin (a child's bicycle)."""
        f = float(factor)
        self._center = [(c[0] * f, c[1] * f, c[2] * f) for c in self._center]
        self._size = [(z[0] * f, z[1] * f, z[2] * f) for z in self._size]

    def shift(self, dx: float, dy: float, dz: float = 0.0) -> None:
        """Move everything added so far by (dx, dy, dz) in the builder's frame."""
        self._center = [(c[0] + dx, c[1] + dy, c[2] + dz) for c in self._center]

    def extend(self, other: PrimitiveBuilder) -> None:
        """Append `other`'s primitives (same frame): a part built and moved on its own builder."""
        self._kind += other._kind
        self._center += other._center
        self._rot += other._rot
        self._size += other._size
        self._sem += other._sem
        self._inst += other._inst
        self._mat += other._mat

    def build(self, pose_rot: np.ndarray | None = None, pose_t: np.ndarray | None = None) -> PrimitiveSet:
        if not self._kind:
            return empty_set()
        rot = np.tile(np.eye(3), (len(self._rot), 1, 1))
        for i, r in enumerate(self._rot):
            if r is not None:
                rot[i] = r
        center = np.array(self._center)
        if pose_rot is not None:
            rot = np.einsum("ij,pjk->pik", pose_rot, rot)
            center = center @ pose_rot.T
        if pose_t is not None:
            center = center + np.asarray(pose_t, float)[None]
        mats = [(m.refl, m.drop, m.spec, m.porosity, m.depth, m.noise, m.grain) for m in self._mat]
        return PrimitiveSet(
            np.array(self._kind, np.int8),
            center,
            rot,
            np.array(self._size),
            np.array(self._sem, np.uint16),
            np.array(self._inst, np.uint16),
            np.array(mats, np.float32),
        )


def primitive_distances(points: np.ndarray, prims: PrimitiveSet) -> np.ndarray:
    """(P, N) signed distance of (N, 3) scene points to each primitive (< 0 inside).

    Exact for boxes, cylinders and capsules; the usual first-order estimate for ellipsoids,
    which is exact on the surface and accurate near it.
    """
    out = np.empty((len(prims), len(points)))
    for i in range(len(prims)):
        local = (points - prims.center[i]) @ prims.rot[i]  # (N, 3) in the local frame
        s = prims.size[i]
        k = prims.kind[i]
        if k == BOX:
            q = np.abs(local) - s
            d = np.linalg.norm(np.maximum(q, 0.0), axis=1) + np.minimum(q.max(axis=1), 0.0)
        elif k == CYLINDER:
            q = np.stack([np.hypot(local[:, 0], local[:, 1]) - s[0], np.abs(local[:, 2]) - s[2]], axis=1)
            d = np.linalg.norm(np.maximum(q, 0.0), axis=1) + np.minimum(q.max(axis=1), 0.0)
        elif k == CAPSULE:
            zc = np.clip(local[:, 2], -s[2], s[2])
            d = np.sqrt(local[:, 0] ** 2 + local[:, 1] ** 2 + (local[:, 2] - zc) ** 2) - s[0]
        else:
            k0 = np.linalg.norm(local / s, axis=1)
            k1 = np.linalg.norm(local / (s * s), axis=1)
            d = k0 * (k0 - 1.0) / np.maximum(k1, 1e-12)
        out[i] = d
    return out


def signed_distance(points: np.ndarray, prims: PrimitiveSet) -> np.ndarray:
    """(N,) signed distance of (N, 3) scene points to the union of `prims` (< 0 inside)."""
    if len(prims) == 0:
        return np.full(len(points), np.inf)
    return primitive_distances(points, prims).min(axis=0)


def surface_distance(points: np.ndarray, prims: PrimitiveSet) -> np.ndarray:
    """(N,) distance of (N, 3) scene points to the nearest primitive surface (inner faces count)."""
    if len(prims) == 0:
        return np.full(len(points), np.inf)
    return np.abs(primitive_distances(points, prims)).min(axis=0)
