"""First-hit ray casting of one revolution against the ground and analytic primitives.

Rays: one per (beam row, azimuth column) of the sensor, row 0 = top beam, column c looking at
azimuth (0.5 - (c + 0.5) / W) * 2 pi (docs/conventions.md). Each primitive is tested only on
the rays of its window: the beam rows and (wrapping) columns that its bounding box covers
as seen from the sensor. Each row keeps the nearest hit per column (one thread: the 2-core target machine is shared).

Foliage and glass are porous (a ray may pass through) and foliage is penetrable (the return
comes from some depth inside); bark has relief (the return comes from up to `depth` below the
surface). Materials with a grain draw pass-through and depth once per texture cell of the
primitive (a counter-based hash of the primitive's key and the cell of the ray's entry point in
the primitive's local frame): neighbouring rays that meet one leaf cluster agree, and the texture
holds still from frame to frame. Farther away a growing share of the depth is drawn per ray
(DECORRELATION_RANGE) and foliage's depth scale grows (FAR_DEPTH): a wider footprint covers more
leaves. Materials without a grain draw per ray from (frame seed, row, column, primitive). Either
way a frame is reproducible whatever the thread count.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from pipeline.sensors import SensorModel
from research.simulation.ground import GroundModel, ground_hit
from research.simulation.shapes import BOX, CAPSULE, CYLINDER, PrimitiveSet

NO_HIT = -1
# Ground hits are stored as hit id -(2 + region).


def ray_directions(sensor: SensorModel) -> np.ndarray:
    """(H, W, 3) float64 unit ray directions in the lidar frame, row 0 = top beam."""
    el = sensor.elevations_rad()
    az = (0.5 - (np.arange(sensor.width) + 0.5) / sensor.width) * 2 * np.pi
    ce = np.cos(el)[:, None]
    return np.stack(
        [ce * np.cos(az)[None], ce * np.sin(az)[None], np.repeat(np.sin(el)[:, None], len(az), 1)], axis=-1
    )


@dataclass(frozen=True)
class Windows:
    """Rays each primitive is tested on.

    row0, row1: (P,) int32 first and last beam row (inclusive); row0 > row1 = no rays.
    col0, ncol: (P,) int32 first column and number of columns (wrapping modulo W).
    """

    row0: np.ndarray
    row1: np.ndarray
    col0: np.ndarray
    ncol: np.ndarray


def ray_windows(prims: PrimitiveSet, rot: np.ndarray, origin: np.ndarray, sensor: SensorModel) -> Windows:
    """Beam and column windows of each primitive for a sensor at `origin` with orientation `rot`.

    rot (3, 3) is R_scene_lidar, origin (3,) the sensor position in the scene frame.
    """
    w = sensor.width
    corners = (prims.corners() - origin[None, None]) @ rot  # (P, 8, 3) lidar frame
    centre = (prims.center - origin[None]) @ rot  # (P, 3)
    rc = np.hypot(centre[:, 0], centre[:, 1])
    rh = np.hypot(corners[..., 0] - centre[:, None, 0], corners[..., 1] - centre[:, None, 1]).max(axis=1)
    inside = rc <= rh + 0.05
    # Azimuth span: corners of the bounding box, relative to the centre's azimuth.
    az_c = np.arctan2(centre[:, 1], centre[:, 0])
    rel = np.angle(np.exp(1j * (np.arctan2(corners[..., 1], corners[..., 0]) - az_c[:, None])))
    az_hi = az_c + rel.max(axis=1)
    az_lo = az_c + rel.min(axis=1)
    c_start = np.floor((0.5 - az_hi / (2 * np.pi)) * w - 0.5).astype(np.int64) - 1
    c_end = np.ceil((0.5 - az_lo / (2 * np.pi)) * w - 0.5).astype(np.int64) + 1
    ncol = np.minimum(c_end - c_start + 1, w)
    col0 = np.mod(c_start, w)
    col0[inside] = 0
    ncol[inside] = w
    # Elevation span, conservative: nearest and farthest horizontal distance of the box.
    zmax = corners[..., 2].max(axis=1)
    zmin = corners[..., 2].min(axis=1)
    rmin = np.maximum(rc - rh, 1e-3)
    rmax = rc + rh
    el_hi = np.arctan2(zmax, np.where(zmax > 0, rmin, rmax))
    el_lo = np.arctan2(zmin, np.where(zmin > 0, rmax, rmin))
    el_hi[inside & (zmax > 0)] = np.pi / 2
    el_lo[inside & (zmin < 0)] = -np.pi / 2
    beams = sensor.elevations_rad()  # descending
    half = 0.5 * np.abs(np.diff(beams)).min()
    row0 = np.searchsorted(-beams, -(el_hi + half), side="left")
    row1 = np.searchsorted(-beams, -(el_lo - half), side="right") - 1
    return Windows(row0.astype(np.int32), row1.astype(np.int32), col0.astype(np.int32), ncol.astype(np.int32))


@dataclass(frozen=True)
class CastResult:
    """Nearest hit per ray.

    t:    (H, W) float32 range along the ray (m), -1 where nothing was hit.
    hit:  (H, W) int32 primitive index >= 0, ground region r as -(2 + r), NO_HIT (-1).
    cosi: (H, W) float32 |cos| of the incidence angle.
    """

    t: np.ndarray
    hit: np.ndarray
    cosi: np.ndarray


def cast(
    dirs_lidar: np.ndarray,
    rot: np.ndarray,
    origin: np.ndarray,
    prims: PrimitiveSet,
    windows: Windows,
    ground: GroundModel,
    max_range: float,
    seed: int,
) -> CastResult:
    """Cast all rays (H, W, 3 lidar directions) from a sensor at `origin` with R_scene_lidar `rot`."""
    dirs = np.ascontiguousarray(dirs_lidar @ rot.T)
    local_rot = np.ascontiguousarray(np.transpose(prims.rot, (0, 2, 1)))  # local from scene
    o_local = np.einsum("pij,pj->pi", local_rot, origin[None] - prims.center)
    mat = prims.material.astype(np.float64)
    t, hit, cosi = _cast_kernel(
        origin.astype(np.float64),
        dirs,
        float(max_range) * 1.02,
        ground.kernel_args(),
        prims.kind.astype(np.int64),
        local_rot,
        np.ascontiguousarray(o_local),
        np.ascontiguousarray(prims.size),
        np.ascontiguousarray(mat[:, 3]),
        np.ascontiguousarray(mat[:, 4]),
        np.ascontiguousarray(mat[:, 6]),
        texture_keys(prims),
        windows.row0,
        windows.row1,
        windows.col0,
        windows.ncol,
        np.uint64(seed & 0xFFFFFFFFFFFFFFFF),
    )
    return CastResult(t, hit, cosi)


def texture_keys(prims: PrimitiveSet) -> np.ndarray:
    """(P,) uint64 key of each primitive's texture: its instance and where it stands, so that a
    static primitive keeps its texture in every frame (and two primitives rarely share one)."""
    pos = np.round(prims.center * 64.0).astype(np.int64).view(np.uint64)  # (P, 3)
    key = prims.instance.astype(np.uint64) * np.uint64(0x9E3779B97F4A7C15)
    for k, mult in enumerate((0xBF58476D1CE4E5B9, 0x94D049BB133111EB, 0xD6E8FEB86659FD93)):
        key ^= pos[:, k] * np.uint64(mult)
    return key


CELL_OFFSET = 1 << 30  # keeps texture cell indices positive for the hash
DECORRELATION_RANGE = 30.0  # metres: beyond it a textured return's depth is drawn per ray
# Foliage depth scale at DECORRELATION_RANGE whatever the plant (growing with range cubed): beyond
# 20 m SemanticKITTI's vegetation, hedges included, scatters 40 cm along rows (median)
FAR_DEPTH = 0.9


@njit(cache=True, inline="always")
def _hash01(seed, a, b, c):  # pragma: no cover - numba
    """Uniform (0, 1) from four integers (splitmix64 finaliser)."""
    x = seed ^ (np.uint64(a) * np.uint64(0x9E3779B97F4A7C15))
    x ^= np.uint64(b) * np.uint64(0xBF58476D1CE4E5B9)
    x ^= np.uint64(c) * np.uint64(0x94D049BB133111EB)
    x ^= x >> np.uint64(30)
    x *= np.uint64(0xBF58476D1CE4E5B9)
    x ^= x >> np.uint64(27)
    x *= np.uint64(0x94D049BB133111EB)
    x ^= x >> np.uint64(31)
    return (np.float64(x >> np.uint64(11)) + 0.5) * (1.0 / 9007199254740992.0)


@njit(cache=True, inline="always")
def _slab(o, d, h, tn, tf, cosi):  # pragma: no cover - numba
    """One axis of the slab test: (tn, tf, cosi) narrowed by the slab |x| <= h, and whether a ray
    parallel to it misses it."""
    if abs(d) < 1e-12:
        return tn, tf, cosi, abs(o) > h
    t1 = (-h - o) / d
    t2 = (h - o) / d
    if t1 > t2:
        t1, t2 = t2, t1
    if t1 > tn:
        tn = t1
        cosi = abs(d)
    return tn, min(tf, t2), cosi, False


@njit(cache=True, inline="always")
def _box(ox, oy, oz, dx, dy, dz, hx, hy, hz):  # pragma: no cover - numba
    tn, tf, cosi, miss = _slab(ox, dx, hx, -1e30, 1e30, 0.0)
    if miss:
        return -1.0, -1.0, 0.0
    tn, tf, cosi, miss = _slab(oy, dy, hy, tn, tf, cosi)
    if miss:
        return -1.0, -1.0, 0.0
    tn, tf, cosi, miss = _slab(oz, dz, hz, tn, tf, cosi)
    if miss:
        return -1.0, -1.0, 0.0
    if tn > tf or tn <= 0.0:
        return -1.0, -1.0, 0.0
    return tn, tf, cosi


@njit(cache=True, inline="always")
def _cylinder(ox, oy, oz, dx, dy, dz, r, hh, caps):  # pragma: no cover - numba
    """Side (and, with caps, end discs) of a cylinder around z; returns (t, cos)."""
    t = 1e30
    cosi = 0.0
    a = dx * dx + dy * dy
    if a > 1e-12:
        b = ox * dx + oy * dy
        c = ox * ox + oy * oy - r * r
        disc = b * b - a * c
        if disc >= 0.0:
            ts = (-b - np.sqrt(disc)) / a
            if ts > 0.0 and abs(oz + ts * dz) <= hh:
                t = ts
                cosi = abs((ox + ts * dx) * dx + (oy + ts * dy) * dy) / r
    if caps and abs(dz) > 1e-12:
        tc = -1.0
        if oz > hh:
            tc = (hh - oz) / dz
        elif oz < -hh:
            tc = (-hh - oz) / dz
        if 0.0 < tc < t:
            x = ox + tc * dx
            y = oy + tc * dy
            if x * x + y * y <= r * r:
                t = tc
                cosi = abs(dz)
    if t >= 1e30:
        return -1.0, 0.0
    return t, cosi


@njit(cache=True, inline="always")
def _sphere(ox, oy, oz, dx, dy, dz, r):  # pragma: no cover - numba
    b = ox * dx + oy * dy + oz * dz
    c = ox * ox + oy * oy + oz * oz - r * r
    disc = b * b - c
    if disc < 0.0:
        return -1.0, -1.0, 0.0
    sq = np.sqrt(disc)
    t = -b - sq
    if t <= 0.0:
        return -1.0, -1.0, 0.0
    cosi = abs((ox + t * dx) * dx + (oy + t * dy) * dy + (oz + t * dz) * dz) / r
    return t, -b + sq, cosi


@njit(cache=True, inline="always")
def _ellipsoid(ox, oy, oz, dx, dy, dz, a, b, c):  # pragma: no cover - numba
    sx = ox / a
    sy = oy / b
    sz = oz / c
    ex = dx / a
    ey = dy / b
    ez = dz / c
    qa = ex * ex + ey * ey + ez * ez
    qb = sx * ex + sy * ey + sz * ez
    qc = sx * sx + sy * sy + sz * sz - 1.0
    disc = qb * qb - qa * qc
    if disc < 0.0:
        return -1.0, -1.0, 0.0
    sq = np.sqrt(disc)
    t = (-qb - sq) / qa
    if t <= 0.0:
        return -1.0, -1.0, 0.0
    nx = (ox + t * dx) / (a * a)
    ny = (oy + t * dy) / (b * b)
    nz = (oz + t * dz) / (c * c)
    cosi = abs(nx * dx + ny * dy + nz * dz) / np.sqrt(nx * nx + ny * ny + nz * nz)
    return t, (-qb + sq) / qa, cosi


@njit(cache=True, inline="always")
def _capsule(ox, oy, oz, dx, dy, dz, r, hl):  # pragma: no cover - numba
    t, cosi = _cylinder(ox, oy, oz, dx, dy, dz, r, hl, False)
    if t < 0.0:
        t = 1e30
    t1, _, c1 = _sphere(ox, oy, oz - hl, dx, dy, dz, r)
    if 0.0 < t1 < t:
        t = t1
        cosi = c1
    t2, _, c2 = _sphere(ox, oy, oz + hl, dx, dy, dz, r)
    if 0.0 < t2 < t:
        t = t2
        cosi = c2
    if t >= 1e30:
        return -1.0, 0.0
    return t, cosi


@njit(cache=True, inline="always")
def _texture(t, tf, ox, oy, oz, dx, dy, dz, por, dep, grn, key, seed, r, c, p):  # pragma: no cover - numba
    """The range of a textured hit entering at t (leaving at tf, -1 for closed surfaces); -1 when
    the ray passes through."""
    if grn > 0.0:
        ix = np.int64(np.floor((ox + t * dx) / grn)) + CELL_OFFSET
        iy = np.int64(np.floor((oy + t * dy) / grn)) + CELL_OFFSET
        iz = np.int64(np.floor((oz + t * dz) / grn)) + CELL_OFFSET
        u_pass = _hash01(key, ix, iy, iz)
        u_cell = _hash01(key ^ np.uint64(0x5851F42D4C957F2D), ix, iy, iz)
        # the farther, the wider the beam's footprint over the texture: the depth of a far return
        # owes more to the ray than to the cell (SemanticKITTI's foliage scatters 3 cm along rows
        # within 10 m and 40 cm beyond 20 m)
        w_ray = min(1.0, max(0.1, t / DECORRELATION_RANGE))
    else:
        u_pass = _hash01(seed, r, c, 2 * p)
        u_cell = 0.5
        w_ray = 1.0
    if por > 0.0 and u_pass < por:
        return -1.0
    if dep > 0.0:
        u_ray = _hash01(seed, r, c, 2 * p + 1)
        if tf > t:  # a volume (foliage): exponential depth, short of the far side
            reach = t / DECORRELATION_RANGE  # a wide footprint's echo comes from deeper leaves
            dep = max(dep, FAR_DEPTH * reach * reach * reach)
            d = -dep * ((1.0 - w_ray) * np.log(u_cell) + w_ray * np.log(u_ray))
            t = t + min(d, 0.9 * (tf - t))
        else:  # a closed surface (bark, boards): relief below it
            t = t + dep * ((1.0 - w_ray) * u_cell + w_ray * u_ray)
    return t


@njit(cache=True)
def _cast_kernel(
    origin, dirs, smax, gargs, kind, local_rot, o_local, size, porosity, depth, grain, keys, row0, row1, col0,
    ncol, seed
):  # pragma: no cover - numba
    h, w = dirs.shape[0], dirs.shape[1]
    bgrid, gorigin, lat, sidx, low_left, low_right, crossings, scal = gargs
    t_out = np.full((h, w), -1.0, dtype=np.float32)
    hit_out = np.full((h, w), -1, dtype=np.int32)
    cos_out = np.zeros((h, w), dtype=np.float32)
    n_prim = kind.shape[0]
    for r in range(h):
        best = np.full(w, 1e30)
        best_id = np.full(w, -1, dtype=np.int32)
        best_cos = np.zeros(w)
        s_guess = -1.0
        for c in range(w):
            tg, region, cg, s_guess = ground_hit(
                origin[0],
                origin[1],
                origin[2],
                dirs[r, c, 0],
                dirs[r, c, 1],
                dirs[r, c, 2],
                smax,
                s_guess,
                bgrid,
                gorigin,
                lat,
                sidx,
                low_left,
                low_right,
                crossings,
                scal,
            )
            if tg > 0.0:
                best[c] = tg
                best_id[c] = -2 - region
                best_cos[c] = cg
        for p in range(n_prim):
            if r < row0[p] or r > row1[p]:
                continue
            m = local_rot[p]
            ox = o_local[p, 0]
            oy = o_local[p, 1]
            oz = o_local[p, 2]
            sa = size[p, 0]
            sb = size[p, 1]
            sc = size[p, 2]
            k = kind[p]
            por = porosity[p]
            dep = depth[p]
            grn = grain[p]
            for j in range(ncol[p]):
                c = (col0[p] + j) % w
                wx = dirs[r, c, 0]
                wy = dirs[r, c, 1]
                wz = dirs[r, c, 2]
                dx = m[0, 0] * wx + m[0, 1] * wy + m[0, 2] * wz
                dy = m[1, 0] * wx + m[1, 1] * wy + m[1, 2] * wz
                dz = m[2, 0] * wx + m[2, 1] * wy + m[2, 2] * wz
                tf = -1.0
                if k == BOX:
                    t, tf, cosi = _box(ox, oy, oz, dx, dy, dz, sa, sb, sc)
                elif k == CYLINDER:
                    t, cosi = _cylinder(ox, oy, oz, dx, dy, dz, sa, sc, True)
                elif k == CAPSULE:
                    t, cosi = _capsule(ox, oy, oz, dx, dy, dz, sa, sc)
                else:
                    t, tf, cosi = _ellipsoid(ox, oy, oz, dx, dy, dz, sa, sb, sc)
                if t <= 0.0 or t >= best[c]:
                    continue
                if por > 0.0 or dep > 0.0:
                    t = _texture(t, tf, ox, oy, oz, dx, dy, dz, por, dep, grn, keys[p], seed, r, c, p)
                    if t <= 0.0 or t >= best[c]:
                        continue
                best[c] = t
                best_id[c] = p
                best_cos[c] = cosi
        for c in range(w):
            if best_id[c] != -1:
                t_out[r, c] = best[c]
                hit_out[r, c] = best_id[c]
                cos_out[r, c] = best_cos[c]
    return t_out, hit_out, cos_out
