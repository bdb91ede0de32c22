"""From ray hits to returns: dropouts, range noise, remission and labels.

A hit becomes a point when its specular echo clears the detector's threshold,

    1 - spec * (1 - smoothstep(0.6, 0.85, cos)) > SPEC_THRESHOLD +- SPEC_JITTER / 2   dark paint, glass

(a panel of dark paint returns or it does not, as on real scans, rather than losing returns at
random), and then with probability

    (1 - drop)                                                          material
  * (1 - exp(-refl * (0.3 + 0.7 cos) * (50 / max(t, 10))^2 / 0.012))   weak echoes far away
  * (1 - RANDOM_DROPOUT)                                                everywhere

so dark cars keep only the panels that face the sensor (plus bumpers, wheels and plates) and
fall apart into several segments. Range noise is Gaussian shot noise (RANGE_SIGMA, growing with
range by RANGE_SIGMA_PER_M, more on foliage and grass) plus a fixed offset per beam (BEAM_BIAS):
each laser of a real sensor keeps its own calibration error, so returns of one beam along a wall
lie on a smooth line while neighbouring beams disagree by a few centimetres (measured on HDL-64E
scans, docs/simulator.md). Remission is reflectivity * (0.35 + 0.65 cos) with 8 % multiplicative
noise and a fixed per-beam gain (+-10 %), as each laser of a real sensor has its own.
Random draws: two uniforms per hit (threshold jitter, keep or drop), then two normals per kept
return. Points stay in ray order: beam by beam from the top beam, each beam in column order.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pipeline.sensors import SensorModel
from research.simulation.ground import REGION_MATERIAL, REGION_SEMANTIC
from research.simulation.raycast import CastResult
from research.simulation.shapes import PrimitiveSet

RANGE_SIGMA = 0.005
RANGE_SIGMA_PER_M = 0.0004
RANDOM_DROPOUT = 0.01
SPEC_THRESHOLD, SPEC_JITTER = 0.5, 0.2
# Each laser of a real HDL-32E reports remission with its own gain; a fixed pattern of +-10 %.
BEAM_GAIN = (1.0 + 0.1 * np.sin(np.arange(64) * 2.399 + 0.7)).astype(np.float32)
# ... and range with its own offset: a fixed pattern of RMS BIAS_SIGMA metres.
BIAS_SIGMA = 0.035
BEAM_BIAS = (BIAS_SIGMA * np.sqrt(2.0) * np.sin(np.arange(64) * 1.618 + 0.3)).astype(np.float32)


@dataclass(frozen=True)
class Returns:
    """One simulated scan.

    points:    (N, 3) float32 lidar frame, in scan order (beam by beam, top beam first).
    remission: (N,) float32 in [0, 1].
    semantic:  (N,) uint16 SemanticKITTI id; instance: (N,) uint16 (0 = ground).
    ring:      (N,) int16 beam row (0 = top beam); column: (N,) int32 azimuth column.
    """

    points: np.ndarray
    remission: np.ndarray
    semantic: np.ndarray
    instance: np.ndarray
    ring: np.ndarray
    column: np.ndarray


def _smoothstep(a: float, b: float, x: np.ndarray) -> np.ndarray:
    u = np.clip((x - a) / (b - a), 0.0, 1.0)
    return u * u * (3 - 2 * u)


def make_returns(
    cast: CastResult,
    prims: PrimitiveSet,
    dirs_lidar: np.ndarray,
    sensor: SensorModel,
    rng: np.random.Generator,
) -> Returns:
    """Turn the nearest hits of one revolution into returns (see the module docstring)."""
    h, w = cast.t.shape
    hit = cast.hit.ravel()
    t = cast.t.ravel()
    idx = np.flatnonzero((hit != -1) & (t >= sensor.min_range) & (t <= sensor.max_range))
    hit = hit[idx]
    t = t[idx]
    cosi = cast.cosi.ravel()[idx]
    n_regions = len(REGION_SEMANTIC)
    row = np.where(hit >= 0, n_regions + hit, -hit - 2)
    table = np.concatenate([REGION_MATERIAL, prims.material])  # (G + P, N_MATERIAL) float32
    refl = table[:, 0][row]
    drop = table[:, 1][row]
    spec = table[:, 2][row]
    gain = 1.0 - spec * (1.0 - _smoothstep(0.6, 0.85, cosi))
    signal = refl * (0.3 + 0.7 * cosi) * (50.0 / np.maximum(t, 10.0)) ** 2
    p = (1.0 - drop) * (1.0 - np.exp(-signal / 0.012)) * (1.0 - RANDOM_DROPOUT)
    u = rng.random((2, len(idx)), dtype=np.float32)
    keep = (gain > SPEC_THRESHOLD + SPEC_JITTER * (u[0] - 0.5)) & (u[1] < p)
    idx, t, cosi, row, refl = idx[keep], t[keep], cosi[keep], row[keep], refl[keep]
    gauss = rng.standard_normal((2, len(idx)), dtype=np.float32)
    sigma = np.sqrt((RANGE_SIGMA + RANGE_SIGMA_PER_M * t) ** 2 + table[:, 5][row] ** 2)
    t_noisy = t + gauss[0] * sigma + BEAM_BIAS[idx // w]
    remission = refl * (0.35 + 0.65 * cosi) * (1.0 + 0.08 * gauss[1]) * BEAM_GAIN[idx // w]
    semantic = np.concatenate([REGION_SEMANTIC, prims.semantic])[row]
    instance = np.concatenate([np.zeros(n_regions, np.uint16), prims.instance])[row]
    points = dirs_lidar.reshape(-1, 3)[idx] * t_noisy[:, None]
    return Returns(
        points=points.astype(np.float32),
        remission=np.clip(remission, 0.0, 1.0).astype(np.float32),
        semantic=semantic.astype(np.uint16),
        instance=instance.astype(np.uint16),
        ring=(idx // w).astype(np.int16),
        column=(idx % w).astype(np.int32),
    )
