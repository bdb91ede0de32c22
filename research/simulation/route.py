"""The campus loop: a closed road centreline of straight segments joined by circular turns.

The loop is a star-shaped polygon (so it never crosses itself) whose corners are rounded by
arcs of 12-25 m radius; it turns left and right. Positions along it are given by the arc
length `s` (metres, wrapping at `length`) and a lateral offset `lat` (metres, + = left of the
direction of travel).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

SAMPLE_STEP = 0.25  # metres between centreline samples


@dataclass(frozen=True)
class Route:
    """A closed centreline sampled every SAMPLE_STEP metres.

    xy:       (M, 2) float64 scene positions of the samples.
    heading:  (M,) float64 unwrapped direction of travel (rad) at each sample.
    straight: (M,) bool, sample lies on a straight segment (not on a turn).
    length:   loop length in metres (= M * SAMPLE_STEP).
    """

    xy: np.ndarray
    heading: np.ndarray
    straight: np.ndarray
    length: float

    def _interp(self, s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        u = np.mod(np.asarray(s, float), self.length) / SAMPLE_STEP
        i0 = np.floor(u).astype(np.int64) % len(self.xy)
        i1 = (i0 + 1) % len(self.xy)
        f = u - np.floor(u)
        return i0, i1, f

    def point(self, s: np.ndarray | float) -> np.ndarray:
        """(..., 2) centreline position at arc length s."""
        i0, i1, f = self._interp(s)
        return self.xy[i0] * (1 - f)[..., None] + self.xy[i1] * f[..., None]

    def yaw(self, s: np.ndarray | float) -> np.ndarray:
        """(...,) direction of travel (rad) at arc length s."""
        i0, i1, f = self._interp(s)
        h0 = self.heading[i0]
        dh = np.angle(np.exp(1j * (self.heading[i1] - h0)))
        return h0 + f * dh

    def offset(self, s: np.ndarray | float, lat: np.ndarray | float) -> np.ndarray:
        """(..., 2) position `lat` metres left of the centreline at arc length s."""
        h = self.yaw(s)
        normal = np.stack([-np.sin(h), np.cos(h)], axis=-1)
        return self.point(s) + np.asarray(lat, float)[..., None] * normal

    def index(self, s: np.ndarray | float) -> np.ndarray:
        """Sample index nearest to arc length s."""
        return np.round(np.mod(np.asarray(s, float), self.length) / SAMPLE_STEP).astype(np.int64) % len(
            self.xy
        )

    def straight_runs(self, margin: float = 0.0) -> list[tuple[float, float]]:
        """(s_start, s_end) of each straight segment, shrunk by `margin` at both ends."""
        runs = []
        st = self.straight
        m = len(st)
        starts = np.flatnonzero(st & ~np.roll(st, 1))
        for a in starts:
            n = 0
            while n < m and st[(a + n) % m]:
                n += 1
            s0 = a * SAMPLE_STEP + margin
            s1 = (a + n) * SAMPLE_STEP - margin
            if s1 > s0:
                runs.append((float(s0), float(s1)))
        return runs

    def turn_starts(self) -> np.ndarray:
        """Arc lengths where a turn begins."""
        st = self.straight
        return np.flatnonzero(st & ~np.roll(st, -1)).astype(float) * SAMPLE_STEP + SAMPLE_STEP


def _polygon(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Corners (n, 2) and fillet radii (n,) of a star-shaped loop meeting the layout limits."""
    for _ in range(1000):
        n = int(rng.integers(5, 8))
        ang = 2 * np.pi * (np.arange(n) + rng.uniform(-0.22, 0.22, n)) / n
        rad = rng.uniform(75.0, 135.0, n)
        pts = np.stack([rad * np.cos(ang), rad * np.sin(ang)], axis=1)
        edge = np.roll(pts, -1, axis=0) - pts
        elen = np.linalg.norm(edge, axis=1)
        head = np.arctan2(edge[:, 1], edge[:, 0])
        turn = np.angle(np.exp(1j * (head - np.roll(head, 1))))  # turn at corner i
        if elen.min() < 55.0 or np.abs(turn).max() > np.deg2rad(115) or np.abs(turn).min() < np.deg2rad(15):
            continue
        radius = rng.uniform(12.0, 25.0, n)
        tangent = radius * np.tan(np.abs(turn) / 2)
        if np.any(tangent + np.roll(tangent, -1) > elen - 25.0):
            continue
        return pts, radius
    raise RuntimeError("could not draw a campus loop")  # pragma: no cover - 1000 tries never all fail


def make_route(rng: np.random.Generator) -> Route:
    """A random closed loop of ~500-800 m, sampled every SAMPLE_STEP metres."""
    pts, radius = _polygon(rng)
    n = len(pts)
    edge = np.roll(pts, -1, axis=0) - pts
    head = np.arctan2(edge[:, 1], edge[:, 0])
    unit = edge / np.linalg.norm(edge, axis=1)[:, None]
    turn = np.angle(np.exp(1j * (head - np.roll(head, 1))))
    tangent = radius * np.tan(np.abs(turn) / 2)
    # Piecewise: turn at corner i (from incoming heading head[i-1] by turn[i]), then edge i.
    xs: list[np.ndarray] = []
    hs: list[np.ndarray] = []
    ss: list[np.ndarray] = []
    h_in = head[-1]
    for i in range(n):
        u_in = unit[i - 1]
        a = pts[i] - tangent[i] * u_in
        sgn = np.sign(turn[i])
        left = np.array([-u_in[1], u_in[0]])
        centre = a + sgn * radius[i] * left
        arc_len = radius[i] * abs(turn[i])
        k = max(2, int(np.ceil(arc_len / 0.05)))
        hh = h_in + turn[i] * np.arange(k) / k
        normal = np.stack([-np.sin(hh), np.cos(hh)], axis=1)
        xs.append(centre[None] - sgn * radius[i] * normal)
        hs.append(hh)
        ss.append(np.zeros(k, bool))
        b = pts[i] + tangent[i] * unit[i]
        e = pts[(i + 1) % n] - tangent[(i + 1) % n] * unit[i]
        line_len = float(np.linalg.norm(e - b))
        k = max(2, int(np.ceil(line_len / 0.05)))
        f = np.arange(k)[:, None] / k
        xs.append(b[None] * (1 - f) + e[None] * f)
        hs.append(np.full(k, head[i]))
        ss.append(np.ones(k, bool))
        h_in = head[i]
    fine = np.concatenate(xs)
    fine_h = np.unwrap(np.concatenate(hs))
    fine_st = np.concatenate(ss)
    seg = np.linalg.norm(np.roll(fine, -1, axis=0) - fine, axis=1)
    cum = np.concatenate([[0.0], np.cumsum(seg)])
    total = cum[-1]
    m = int(np.floor(total / SAMPLE_STEP))
    length = m * SAMPLE_STEP
    # Resample at exact SAMPLE_STEP spacing; the small remainder is spread over the loop.
    s_new = np.arange(m) * (total / m)
    closed = np.vstack([fine, fine[:1]])
    x = np.interp(s_new, cum, closed[:, 0])
    y = np.interp(s_new, cum, closed[:, 1])
    h = np.interp(s_new, cum, np.concatenate([fine_h, [fine_h[0] + 2 * np.pi * np.sign(turn.sum())]]))
    straight = np.interp(s_new, cum[:-1], fine_st.astype(float)) > 0.5
    return Route(np.stack([x, y], axis=1), h, straight, float(length))


@dataclass(frozen=True)
class EgoProfile:
    """Arc length of the ego vehicle over time: s(t) = s0 + v0 t + a smooth speed wobble.

    speed(t) = v0 + amp * sin(2 pi t / period + phase); `lat` is the ego lane offset.
    """

    s0: float
    v0: float
    amp: float
    period: float
    phase: float
    lat: float

    def s_at(self, t: np.ndarray | float) -> np.ndarray:
        t = np.asarray(t, float)
        w = 2 * np.pi / self.period
        return self.s0 + self.v0 * t + self.amp / w * (np.cos(self.phase) - np.cos(w * t + self.phase))

    def speed(self, t: np.ndarray | float) -> np.ndarray:
        return self.v0 + self.amp * np.sin(2 * np.pi * np.asarray(t, float) / self.period + self.phase)

    def time_at(self, s: float, length: float) -> float:
        """First time t >= 0 at which the ego reaches arc length s (mod `length`)."""
        target = self.s0 + np.mod(s - self.s0, length)
        lo, hi = 0.0, (target - self.s0) / (self.v0 - self.amp) + 1.0
        for _ in range(60):
            mid = 0.5 * (lo + hi)
            if self.s_at(mid) < target:
                lo = mid
            else:
                hi = mid
        return 0.5 * (lo + hi)


def make_ego_profile(rng: np.random.Generator, route: Route, lane_offset: float) -> EgoProfile:
    """Start ~30 m before a turn so that even short runs see the heading change."""
    turns = route.turn_starts()
    s_turn = float(turns[int(rng.integers(len(turns)))])
    return EgoProfile(
        s0=s_turn - rng.uniform(25.0, 35.0),
        v0=rng.uniform(4.6, 5.4),
        amp=rng.uniform(0.3, 0.7),
        period=rng.uniform(20.0, 40.0),
        phase=rng.uniform(0, 2 * np.pi),
        lat=-lane_offset,
    )
