"""How the reviewed track looks: real colours (height or intensity), an outline box, the
aggregated cloud of its kept frames and its top / side orthographic images. Pure numpy; the
viewer and the track views panel draw what these return.

Frames: every (N, 3) array here is in one frame the caller chose (the scene's: the shown
frame's lidar frame, z up); `aggregate` takes world points and returns world points.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

# a perceptual ramp (dark blue -> teal -> yellow), readable on the dark scene background
_RAMP = np.array([[68, 1, 84], [59, 82, 139], [33, 145, 140], [94, 201, 98], [253, 231, 37]], np.float64)
OUTLINE = (255, 215, 0)
TRACK_LOOKS = ("height", "intensity")


def ramp_colours(values: np.ndarray, lo: float, hi: float) -> np.ndarray:
    """(N, 3) uint8 colours of (N,) values on the ramp, lo..hi (clipped)."""
    t = np.clip((np.asarray(values, np.float64) - lo) / max(hi - lo, 1e-6), 0.0, 1.0) * (len(_RAMP) - 1)
    i = np.minimum(t.astype(np.int64), len(_RAMP) - 2)
    f = (t - i)[:, None]
    return ((1 - f) * _RAMP[i] + f * _RAMP[i + 1]).astype(np.uint8)


def track_colours(points: np.ndarray, intensity: np.ndarray, look: str) -> np.ndarray:
    """(N, 3) uint8: height (the track's own z range) or intensity (0..1) on the ramp."""
    if look == "intensity":
        return ramp_colours(intensity, 0.0, max(float(np.percentile(intensity, 98)) if len(intensity) else 1.0, 1e-3))
    z = points[:, 2]
    return ramp_colours(z, float(z.min(initial=0.0)), float(z.max(initial=1.0)))


def box_outline(points: np.ndarray, pad: float = 0.15) -> np.ndarray:
    """(12, 2, 3) float32 edges of the points' axis-aligned box, `pad` metres wider each side."""
    lo, hi = points.min(axis=0) - pad, points.max(axis=0) + pad
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])], np.float32)
    edges = [(a, b) for a in range(8) for b in range(a + 1, 8) if bin(a ^ b).count("1") == 1]
    return np.stack([corners[[a, b]] for a, b in edges])


@dataclass(frozen=True)
class FrameCut:
    """One kept frame's track points for the aggregated view: (N, 3) world points, (N,)
    intensity, and the track's (3,) world centroid in that frame."""

    points_world: np.ndarray
    intensity: np.ndarray
    centroid_world: np.ndarray


def aggregate(cuts: list[FrameCut], compensate: bool, anchor: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """All frames' points overlaid in the world frame: (M, 3) points and (M,) intensity. With
    `compensate`, each frame's points are moved by (anchor - its centroid), so a moving object
    lines up at `anchor` ((3,), default the first frame's centroid) as if it stood still."""
    if not cuts:
        return np.zeros((0, 3), np.float32), np.zeros(0, np.float32)
    anchor = cuts[0].centroid_world if anchor is None else anchor
    pts = [c.points_world + (anchor - c.centroid_world if compensate else 0.0) for c in cuts]
    return np.concatenate(pts).astype(np.float32), np.concatenate([c.intensity for c in cuts]).astype(np.float32)


def ortho_image(points: np.ndarray, colours: np.ndarray, view: str, size: int = 220, margin: float = 0.5) -> np.ndarray:
    """(size, size, 3) uint8 orthographic image of the points: `top` looks down -z (x right,
    y up), `side` looks along +y (x right, z up). Equal metres per pixel on both axes, a grid
    line every metre; the nearest point wins each pixel (highest for top, nearest for side)."""
    img = np.full((size, size, 3), 24, np.uint8)
    if len(points) == 0:
        return img
    u_axis, v_axis, depth_axis, nearest_is_max = (0, 1, 2, True) if view == "top" else (0, 2, 1, False)
    u, v = points[:, u_axis].astype(np.float64), points[:, v_axis].astype(np.float64)
    span = max(np.ptp(u), np.ptp(v)) + 2 * margin
    scale = (size - 1) / span
    u0, v0 = (u.min() + u.max() - span) / 2, (v.min() + v.max() - span) / 2
    for m in np.arange(np.ceil(u0), u0 + span, 1.0):
        img[:, int((m - u0) * scale)] = (48, 48, 48)
    for m in np.arange(np.ceil(v0), v0 + span, 1.0):
        img[size - 1 - int((m - v0) * scale), :] = (48, 48, 48)
    col = ((u - u0) * scale).astype(np.int64).clip(0, size - 1)
    row = (size - 1 - ((v - v0) * scale).astype(np.int64)).clip(0, size - 1)
    depth = points[:, depth_axis]
    order = np.argsort(depth if nearest_is_max else -depth)  # drawn last = on top
    img[row[order], col[order]] = colours[order]
    # 2x2 splats: single pixels vanish when the image is shown scaled down
    img[np.minimum(row[order] + 1, size - 1), col[order]] = colours[order]
    img[row[order], np.minimum(col[order] + 1, size - 1)] = colours[order]
    return img
