"""What a model's inputs looked like in training, and whether a sequence's inputs look the same.

A checkpoint stores (`pipeline.model.save_checkpoint`, key `input_stats`):

- `channels`: per canvas channel (height, range, intensity, foreground), the 1st, 5th, 50th,
  95th and 99th percentiles over training canvases of each canvas's mean over its non-empty
  pixels (range > 0), in [0, 1] (`canvas_stats`);
- `sensor_intensity` (when the trainer knows its sensors): the 5th, 50th and 95th percentiles of
  the raw intensities the training sensors reported (`sensor_intensity_stats`), before any
  normalisation.

`input_warnings` compares a sequence with them and names each channel that lies outside: a
sensor without intensity, raw intensities on another scale than the training sensors' (normalised
per sensor when the model reads ranks, `pipeline.intensity`), and canvases whose typical channel
mean lies outside the training canvases' 1st-99th percentile.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from pipeline.intensity import is_absent

CHANNELS = ("height", "range", "intensity", "foreground")
PERCENTILES = (1, 5, 50, 95, 99)
MAX_CANVASES = 4000  # a random subset of the training canvases: the percentiles are stable by then
MIN_CANVASES = 20  # fewer input canvases say nothing about a channel
CHUNK = 256


def canvas_means(samples: np.ndarray) -> np.ndarray:
    """(V, C) float64 mean of each channel over each canvas's non-empty pixels (range channel 1
    > 0), in [0, 1]; NaN for an empty canvas. samples: (V, C, S, S) uint8."""
    x = np.asarray(samples)
    out = np.empty(x.shape[:2], dtype=np.float64)
    for start in range(0, len(x), CHUNK):  # float32 copies of a few hundred canvases at a time
        part = x[start : start + CHUNK].astype(np.float32)  # (v, C, S, S)
        hit = part[:, 1] > 0  # (v, S, S)
        n = hit.sum(axis=(1, 2)).astype(np.float64)  # (v,)
        sums = (part * hit[:, None]).sum(axis=(2, 3), dtype=np.float64)  # (v, C)
        with np.errstate(invalid="ignore", divide="ignore"):
            out[start : start + CHUNK] = sums / n[:, None] / 255.0
    return out


def canvas_stats(samples: np.ndarray, seed: int = 0) -> dict[str, Any]:
    """Percentiles of the per-canvas channel means of (M, C, S, S) uint8 training canvases (at
    most MAX_CANVASES of them, drawn at random)."""
    m = len(samples)
    if m == 0:
        return {}
    pick = np.sort(np.random.default_rng(seed).choice(m, min(m, MAX_CANVASES), replace=False))
    means = canvas_means(samples[pick])
    out: dict[str, Any] = {"canvases": int(len(pick)), "channels": {}}
    for c in range(means.shape[1]):
        col = means[:, c][np.isfinite(means[:, c])]
        if len(col):
            out["channels"][CHANNELS[c]] = {f"p{p}": round(float(np.percentile(col, p)), 4) for p in PERCENTILES}
    return out


def sensor_intensity_stats(quantiles: list[tuple[float, ...]]) -> dict[str, float]:
    """5th, 50th and 95th percentile of raw intensity pooled over sensors' measured quantiles
    (`SensorModel.intensity_quantiles`, p0..p100 each); {} when none was measured."""
    pooled = np.concatenate([np.asarray(q, dtype=np.float64) for q in quantiles if len(q) >= 2] or [np.zeros(0)])
    if len(pooled) == 0:
        return {}
    return {f"p{p}": round(float(np.percentile(pooled, p)), 6) for p in (5, 50, 95)}


def _sensor_warnings(stats: dict[str, Any], quantiles: tuple[float, ...], sample_mode: str) -> list[str]:
    if is_absent(quantiles):
        return [f"intensity: the input has none (every value is {quantiles[0]:g}); the model reads an empty "
                "intensity channel, its geometry-only input" + ("" if sample_mode == "sensor" else
                                                                  ", which this model was not trained on")]
    train = stats.get("sensor_intensity") or {}
    if len(quantiles) < 2 or not train:
        return []
    q = np.asarray(quantiles)
    median, top = float(np.median(q)), float(q[int(round(0.99 * (len(q) - 1)))])
    if train["p5"] <= median <= train["p95"]:
        return []
    how = "scaled per sensor (its 95th percentile to 0.5)" if sample_mode == "sensor" else "as they are (this model reads raw values)"
    return [f"intensity: the input's values (median {median:.3g}, 99th percentile {top:.3g}) lie outside the "
            f"training data's (5th-95th percentile {train['p5']:.3g}-{train['p95']:.3g}); the model sees them {how}"]


def input_warnings(
    stats: dict[str, Any], samples: np.ndarray, quantiles: tuple[float, ...] = (), sample_mode: str = "sensor"
) -> list[str]:
    """Warnings, each naming its channel, where a sequence's inputs lie outside a checkpoint's
    training `stats`: `quantiles` the sequence sensor's raw intensity quantiles
    (`SensorModel.intensity_quantiles`), `samples` (V, C, S, S) uint8 canvases of the sequence,
    `sample_mode` the model's `SampleConfig.intensity`. [] when `stats` is empty (an older
    checkpoint) except for a sensor without intensity."""
    out = _sensor_warnings(stats, quantiles, sample_mode)
    absent = bool(out) and is_absent(quantiles)
    channels = stats.get("channels") or {}
    means = canvas_means(samples) if len(samples) >= MIN_CANVASES else np.zeros((0, 0))
    for c, name in enumerate(CHANNELS[: means.shape[1]]):
        band = channels.get(name)
        col = means[:, c][np.isfinite(means[:, c])]
        if band is None or len(col) < MIN_CANVASES or (absent and name == "intensity"):
            continue
        typical = float(np.median(col))
        if not band["p1"] <= typical <= band["p99"]:
            out.append(f"{name}: the input canvases' typical mean {typical:.3f} lies outside the training "
                       f"canvases' 1st-99th percentile ({band['p1']:.3f}-{band['p99']:.3f})")
    return out
