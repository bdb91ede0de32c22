"""The ground: a gently rolling surface with a road, curbs, sidewalks, parking and grass.

Height = base(x, y) + level, where base is a sum of three long sine waves (slopes of a few
per cent, |base| < 0.8 m) and level is 0 on the low surfaces (road, parking bays and lots)
and `curb` (~0.13 m) elsewhere, so every road edge is a curb step.

Regions are decided by the signed lateral distance to the route centreline (a 0.5 m grid,
bilinear) and the nearest centreline sample (for per-sample bay widths and markings):

    |lat| <= road_half                     road (painted lines and zebra crossings)
    road_half < |lat| <= low_width(s)      parking (bays and lots), low
    low_width(s) < |lat| <= + sidewalk     sidewalk, raised
    beyond                                 terrain (grass), raised
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numba import njit
from scipy.ndimage import distance_transform_edt

from research.simulation.route import SAMPLE_STEP, Route

# Region codes of ground hits (the ray caster stores them as negative hit ids).
ROAD, MARKING, PARKING, SIDEWALK, CURB, TERRAIN = range(6)
REGION_SEMANTIC = np.array([40, 40, 44, 48, 48, 72], np.uint16)
# Material rows (refl, drop, spec, porosity, depth, noise, grain) per region.
REGION_MATERIAL = np.array(
    [
        [0.10, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0],
        [0.55, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0],
        [0.13, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0],
        [0.30, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0],
        [0.35, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0],
        [0.24, 0.02, 0.0, 0.0, 0.0, 0.015, 0.0],
    ],
    np.float32,
)
GRID_CELL = 0.5
GRID_MARGIN = 125.0
BASE_CELL = 1.0  # the ray caster reads base heights from a bilinear grid (error < 1 mm)


@dataclass(frozen=True)
class GroundModel:
    """Everything the ray caster needs to intersect the ground.

    waves:      (3, 4) float64 rows kx, ky, phase, amplitude of base(x, y).
    origin:     (2,) scene xy of grid cell (0, 0); cell size GRID_CELL.
    lat:        (nx, ny) float32 signed lateral distance to the centreline (+ = left).
    sidx:       (nx, ny) int32 nearest centreline sample.
    low_left:   (M,) float32 half width of the low surface left of sample m (road + bays).
    low_right:  (M,) float32 the same on the right.
    crossings:  (K,) float64 arc lengths of zebra crossings.
    base_grid:  (bx, by) float64 base height every BASE_CELL metres from `origin` (ray caster).
    """

    waves: np.ndarray
    origin: np.ndarray
    lat: np.ndarray
    sidx: np.ndarray
    low_left: np.ndarray
    low_right: np.ndarray
    crossings: np.ndarray
    road_half: float
    sidewalk_left: float
    sidewalk_right: float
    curb: float
    route_length: float
    base_grid: np.ndarray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        nx, ny = self.lat.shape
        bx = int(np.ceil(nx * GRID_CELL / BASE_CELL)) + 2
        by = int(np.ceil(ny * GRID_CELL / BASE_CELL)) + 2
        gx = self.origin[0] + BASE_CELL * np.arange(bx)
        gy = self.origin[1] + BASE_CELL * np.arange(by)
        pts = np.stack(np.meshgrid(gx, gy, indexing="ij"), axis=-1).reshape(-1, 2)
        object.__setattr__(self, "base_grid", self.base(pts).reshape(bx, by))

    def kernel_args(self) -> tuple:
        """The fields as the tuple `ground_hit` takes."""
        return (
            self.base_grid,
            self.origin,
            self.lat,
            self.sidx,
            self.low_left,
            self.low_right,
            self.crossings,
            np.array([self.road_half, self.sidewalk_left, self.sidewalk_right, self.curb, self.route_length]),
        )

    def base(self, xy: np.ndarray) -> np.ndarray:
        """(N,) base height at (N, 2) scene points."""
        w = self.waves
        arg = xy[:, :1] * w[None, :, 0] + xy[:, 1:2] * w[None, :, 1] + w[None, :, 2]
        return (np.sin(arg) * w[None, :, 3]).sum(axis=1)

    def gradient(self, xy: np.ndarray) -> np.ndarray:
        """(N, 2) gradient of the base height."""
        w = self.waves
        arg = xy[:, :1] * w[None, :, 0] + xy[:, 1:2] * w[None, :, 1] + w[None, :, 2]
        c = np.cos(arg) * w[None, :, 3]
        return np.stack([(c * w[None, :, 0]).sum(axis=1), (c * w[None, :, 1]).sum(axis=1)], axis=1)

    def lateral(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """((N,) signed lateral distance, (N,) nearest sample, -1 off the grid) at (N, 2) points."""
        f = (xy - self.origin[None]) / GRID_CELL
        nx, ny = self.lat.shape
        i = np.floor(f).astype(np.int64)
        inside = (i[:, 0] >= 0) & (i[:, 1] >= 0) & (i[:, 0] < nx - 1) & (i[:, 1] < ny - 1)
        i = np.where(inside[:, None], i, 0)
        u = f - i
        la = self.lat
        lat = (
            la[i[:, 0], i[:, 1]] * (1 - u[:, 0]) * (1 - u[:, 1])
            + la[i[:, 0] + 1, i[:, 1]] * u[:, 0] * (1 - u[:, 1])
            + la[i[:, 0], i[:, 1] + 1] * (1 - u[:, 0]) * u[:, 1]
            + la[i[:, 0] + 1, i[:, 1] + 1] * u[:, 0] * u[:, 1]
        )
        r = np.clip(np.round(f).astype(np.int64), 0, [nx - 1, ny - 1])
        sidx = self.sidx[r[:, 0], r[:, 1]]
        return np.where(inside, lat, 1e9), np.where(inside, sidx, -1)

    def low(self, xy: np.ndarray) -> np.ndarray:
        """(N,) bool: the point lies on the low surface (road, bay or lot)."""
        lat, si = self.lateral(xy)
        si = np.maximum(si, 0)
        return (lat <= self.low_left[si]) & (lat >= -self.low_right[si])

    def height(self, xy: np.ndarray) -> np.ndarray:
        """(N,) ground height at (N, 2) scene points (curb steps included)."""
        xy = np.atleast_2d(xy)
        return self.base(xy) + np.where(self.low(xy), 0.0, self.curb)

    def normal(self, xy: np.ndarray) -> np.ndarray:
        """(N, 3) unit normal of the base surface."""
        g = self.gradient(np.atleast_2d(xy))
        n = np.concatenate([-g, np.ones((len(g), 1))], axis=1)
        return n / np.linalg.norm(n, axis=1, keepdims=True)


def make_waves(rng: np.random.Generator) -> np.ndarray:
    """(3, 4) wave table: wavelengths 70-220 m, slope of each wave <= 1.2 %, |base| < 0.8 m."""
    rows = []
    for _ in range(3):
        lam = rng.uniform(70.0, 220.0)
        k = 2 * np.pi / lam
        d = rng.uniform(0, 2 * np.pi)
        amp = min(rng.uniform(0.1, 0.26), 0.012 / k)
        rows.append([k * np.cos(d), k * np.sin(d), rng.uniform(0, 2 * np.pi), amp])
    return np.asarray(rows)


def lateral_grid(route: Route) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(origin (2,), lat (nx, ny) float32, sidx (nx, ny) int32) over the loop plus GRID_MARGIN.

    The nearest sample comes from a Euclidean distance transform of the rasterised centreline;
    the lateral distance is then exact: the offset from that sample along its normal.
    """
    lo = route.xy.min(axis=0) - GRID_MARGIN
    hi = route.xy.max(axis=0) + GRID_MARGIN
    nx, ny = (np.ceil((hi - lo) / GRID_CELL).astype(int) + 1).tolist()
    cells = np.round((route.xy - lo[None]) / GRID_CELL).astype(np.int64)
    seed = np.full((nx, ny), -1, np.int64)
    seed[cells[:, 0], cells[:, 1]] = np.arange(len(route.xy))
    dist, (ix, iy) = distance_transform_edt(seed < 0, return_indices=True)
    idx = seed[ix, iy]
    gx = lo[0] + GRID_CELL * np.arange(nx)
    gy = lo[1] + GRID_CELL * np.arange(ny)
    # Near the road, refine to the truly nearest sample among the neighbours along the loop.
    near = dist * GRID_CELL < 25.0
    cand = idx[near][:, None] + np.arange(-8, 9)[None]
    cand %= len(route.xy)
    px = np.broadcast_to(gx[:, None], (nx, ny))[near]
    py = np.broadcast_to(gy[None, :], (nx, ny))[near]
    d2 = (route.xy[cand, 0] - px[:, None]) ** 2 + (route.xy[cand, 1] - py[:, None]) ** 2
    idx[near] = cand[np.arange(len(cand)), np.argmin(d2, axis=1)]
    h = route.heading[idx]
    dx = gx[:, None] - route.xy[idx, 0]
    dy = gy[None, :] - route.xy[idx, 1]
    lat = -np.sin(h) * dx + np.cos(h) * dy
    return lo, lat.astype(np.float32), idx.astype(np.int32)


# ---------------------------------------------------------------- numba side (ray caster)


@njit(cache=True, inline="always")
def _base_grad(x, y, bgrid, origin):  # pragma: no cover - numba
    """Bilinear base height and its gradient from the BASE_CELL grid (clamped at the edges)."""
    fx = (x - origin[0]) / BASE_CELL
    fy = (y - origin[1]) / BASE_CELL
    ix = min(max(int(np.floor(fx)), 0), bgrid.shape[0] - 2)
    iy = min(max(int(np.floor(fy)), 0), bgrid.shape[1] - 2)
    u = min(max(fx - ix, 0.0), 1.0)
    v = min(max(fy - iy, 0.0), 1.0)
    h00 = bgrid[ix, iy]
    h10 = bgrid[ix + 1, iy]
    h01 = bgrid[ix, iy + 1]
    h11 = bgrid[ix + 1, iy + 1]
    b = h00 * (1 - u) * (1 - v) + h10 * u * (1 - v) + h01 * (1 - u) * v + h11 * u * v
    gx = ((h10 - h00) * (1 - v) + (h11 - h01) * v) / BASE_CELL
    gy = ((h01 - h00) * (1 - u) + (h11 - h10) * u) / BASE_CELL
    return b, gx, gy


@njit(cache=True, inline="always")
def _lookup(x, y, origin, lat, sidx):  # pragma: no cover - numba
    fx = (x - origin[0]) / GRID_CELL
    fy = (y - origin[1]) / GRID_CELL
    ix = int(np.floor(fx))
    iy = int(np.floor(fy))
    if ix < 0 or iy < 0 or ix >= lat.shape[0] - 1 or iy >= lat.shape[1] - 1:
        return 1e9, -1
    u = fx - ix
    v = fy - iy
    la = (
        lat[ix, iy] * (1 - u) * (1 - v)
        + lat[ix + 1, iy] * u * (1 - v)
        + lat[ix, iy + 1] * (1 - u) * v
        + lat[ix + 1, iy + 1] * u * v
    )
    return la, sidx[ix + int(u >= 0.5), iy + int(v >= 0.5)]


@njit(cache=True, inline="always")
def _is_low(x, y, origin, lat, sidx, low_left, low_right):  # pragma: no cover - numba
    la, si = _lookup(x, y, origin, lat, sidx)
    if si < 0:
        return False
    if la >= 0:
        return la <= low_left[si]
    return -la <= low_right[si]


@njit(cache=True, inline="always")
def _solve_level(ox, oy, oz, dx, dy, dz, h, bgrid, origin, smax, s_init):  # pragma: no cover - numba
    """Ray parameter where the ray meets base + h (Newton from s_init, or the flat guess), or -1."""
    s = s_init
    if s <= 0.0:
        b, gx, gy = _base_grad(ox, oy, bgrid, origin)
        s = max((oz - b - h) / (-dz), 0.0)
    for _ in range(10):
        b, gx, gy = _base_grad(ox + s * dx, oy + s * dy, bgrid, origin)
        f = oz + s * dz - b - h
        fp = dz - (gx * dx + gy * dy)
        if fp > -1e-5:
            return -1.0
        step = f / fp
        s -= step
        if s > smax * 1.5:
            return -1.0
        if abs(step) < 2e-4:
            break
    if s <= 0.0 or s > smax:
        return -1.0
    return s


@njit(cache=True, inline="always")
def _region(x, y, origin, lat, sidx, low_left, low_right, crossings, scal):  # pragma: no cover - numba
    road_half = scal[0]
    length = scal[4]
    la, si = _lookup(x, y, origin, lat, sidx)
    if si < 0:
        return TERRAIN
    a = abs(la)
    wl = low_left[si] if la >= 0 else low_right[si]
    if a <= wl:
        if a > road_half:
            return PARKING
        s = si * SAMPLE_STEP
        if a < 0.06 and (s % 9.0) < 4.5:
            return MARKING
        if abs(a - (road_half - 0.3)) < 0.06:
            return MARKING
        for k in range(crossings.shape[0]):
            ds = abs(s - crossings[k])
            ds = min(ds, length - ds)
            if ds < 1.8 and ((la + 10.0) % 1.0) < 0.5 and a < road_half - 0.4:
                return MARKING
        return ROAD
    sw = scal[1] if la >= 0 else scal[2]
    if a <= wl + sw:
        return SIDEWALK
    return TERRAIN


@njit(cache=True, inline="always")
def ground_hit(
    ox, oy, oz, dx, dy, dz, smax, s_init, bgrid, origin, lat, sidx, low_left, low_right, crossings, scal
):  # pragma: no cover - numba
    """(t, region, cos incidence, t of the raised level) of a ray with the ground; t = -1 on a miss.

    s_init: a guess of where the ray meets the raised level (the neighbouring ray's), or -1.
    """
    if dz > -1e-3:
        return -1.0, -1, 0.0, -1.0
    curb = scal[3]
    s_hi = _solve_level(ox, oy, oz, dx, dy, dz, curb, bgrid, origin, smax, s_init)
    if s_hi < 0:
        return -1.0, -1, 0.0, -1.0
    hx = ox + s_hi * dx
    hy = oy + s_hi * dy
    _, gx, gy = _base_grad(hx, hy, bgrid, origin)
    if not _is_low(hx, hy, origin, lat, sidx, low_left, low_right):
        cosi = abs(-gx * dx - gy * dy + dz) / np.sqrt(gx * gx + gy * gy + 1.0)
        return s_hi, _region(hx, hy, origin, lat, sidx, low_left, low_right, crossings, scal), cosi, s_hi
    s_lo = _solve_level(
        ox, oy, oz, dx, dy, dz, 0.0, bgrid, origin, smax, s_hi + curb / (gx * dx + gy * dy - dz)
    )
    if s_lo < 0:
        return -1.0, -1, 0.0, s_hi
    lx = ox + s_lo * dx
    ly = oy + s_lo * dy
    if _is_low(lx, ly, origin, lat, sidx, low_left, low_right):
        _, gx, gy = _base_grad(lx, ly, bgrid, origin)
        cosi = abs(-gx * dx - gy * dy + dz) / np.sqrt(gx * gx + gy * gy + 1.0)
        return s_lo, _region(lx, ly, origin, lat, sidx, low_left, low_right, crossings, scal), cosi, s_hi
    # The ray enters a raised surface between the two levels: it meets the curb face.
    a = s_hi
    b = s_lo
    for _ in range(7):
        m = 0.5 * (a + b)
        if _is_low(ox + m * dx, oy + m * dy, origin, lat, sidx, low_left, low_right):
            a = m
        else:
            b = m
    return b, CURB, 0.8 * np.sqrt(dx * dx + dy * dy), s_hi
