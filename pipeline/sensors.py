"""Sensor models: beam elevations, range-image width, rate and range limits.

Rows of a range image follow the beams from the top: row 0 is the beam with the highest
elevation. `SensorModel.elevations_deg` is therefore sorted in descending order.

A sequence's sensor is decided once, and how it was decided is kept with it (`SENSOR_FROM`): the
user's flag, the data's metadata (a simulator's metadata.json, an Ouster json), a ring field, an
organized H x W layout, the scan order of the points, or the elevation histogram of an unordered
cloud (`pipeline.io.layout`). Beams found in the data become a preset when their count and
elevations match one (`sensor_from_elevations`).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pipeline.errors import DataError


@dataclass(frozen=True)
class SensorModel:
    """A spinning multi-beam LiDAR.

    elevations_deg: (R,) beam elevations in degrees, descending (row 0 = top beam).
    width: azimuth bins of one revolution (range-image columns).
    intensity_quantiles: p0..p100 of the sensor's intensities measured on a sequence's first
    frame (`pipeline.intensity`), () when not measured; sample canvases show intensity by rank
    among them.
    ego_box: (x_min, x_max, y_min, y_max, z_min, z_max) metres in the lidar frame: the vehicle
    the sensor is mounted on, whose returns are no scene (never segmented, label 0); () = none.
    """

    name: str
    elevations_deg: tuple[float, ...]
    width: int
    frequency_hz: float = 10.0
    min_range: float = 1.0
    max_range: float = 100.0
    intensity_quantiles: tuple[float, ...] = ()
    ego_box: tuple[float, ...] = ()

    def __post_init__(self) -> None:
        el = np.asarray(self.elevations_deg)
        if el.ndim != 1 or len(el) < 2:
            raise ValueError(f"sensor {self.name}: needs at least two beam elevations")
        if np.any(np.diff(el) >= 0):
            raise ValueError(f"sensor {self.name}: elevations must be strictly descending (row 0 = top)")
        if self.width < 8:
            raise ValueError(f"sensor {self.name}: width must be >= 8, got {self.width}")
        check_ego_box(self.ego_box, f"sensor {self.name}")

    @property
    def n_rings(self) -> int:
        return len(self.elevations_deg)

    def elevations_rad(self) -> np.ndarray:
        """(R,) float64 beam elevations in radians, descending."""
        return np.deg2rad(np.asarray(self.elevations_deg, dtype=np.float64))

    def to_dict(self) -> dict:
        return {
            "name": self.name,
            "elevations_deg": list(self.elevations_deg),
            "width": self.width,
            "frequency_hz": self.frequency_hz,
            "min_range": self.min_range,
            "max_range": self.max_range,
            "intensity_quantiles": list(self.intensity_quantiles),
            "ego_box": list(self.ego_box),
        }

    @classmethod
    def from_dict(cls, d: dict) -> SensorModel:
        return cls(
            name=str(d["name"]),
            elevations_deg=tuple(float(x) for x in d["elevations_deg"]),
            width=int(d["width"]),
            frequency_hz=float(d.get("frequency_hz", 10.0)),
            min_range=float(d.get("min_range", 1.0)),
            max_range=float(d.get("max_range", 100.0)),
            intensity_quantiles=tuple(float(x) for x in d.get("intensity_quantiles", ())),
            ego_box=tuple(float(x) for x in d.get("ego_box", ())),
        )


def check_ego_box(box: tuple[float, ...], where: str) -> None:
    """ValueError naming `where` unless `box` is () or (x_min, x_max, y_min, y_max, z_min, z_max)
    with each minimum below its maximum."""
    if len(box) == 0:
        return
    if len(box) != 6 or any(lo >= hi for lo, hi in zip(box[::2], box[1::2], strict=True)):
        raise ValueError(f"{where}: ego_box must be (x_min, x_max, y_min, y_max, z_min, z_max), each min < max; got {box}")


def _hdl32e() -> SensorModel:
    # 32 beams from +10.67 deg down to -30.67 deg in 1.333 deg steps.
    el = np.linspace(10.67, -30.67, 32)
    return SensorModel("hdl32e", tuple(float(x) for x in el), width=2160, min_range=1.0, max_range=100.0)


def _hdl64e() -> SensorModel:
    # KITTI's HDL-64E: upper block +2.0 .. -8.33 deg (1/3 deg), lower block -8.83 .. -24.33 deg (1/2 deg).
    upper = np.linspace(2.0, -8.33, 32)
    lower = np.linspace(-8.83, -24.33, 32)
    el = np.concatenate([upper, lower])
    return SensorModel("hdl64e", tuple(float(x) for x in el), width=2048, min_range=2.5, max_range=120.0)


def _vlp16() -> SensorModel:
    el = np.linspace(15.0, -15.0, 16)
    return SensorModel("vlp16", tuple(float(x) for x in el), width=1800, min_range=0.5, max_range=100.0)


PRESETS: dict[str, SensorModel] = {"hdl32e": _hdl32e(), "hdl64e": _hdl64e(), "vlp16": _vlp16()}


# How a sequence's sensor was decided, as `tracklabel inspect` prints it.
SENSOR_FROM = (
    "user flag", "metadata", "ring field", "organized layout", "scan order", "elevation histogram", "default",
)
# Beams found in the data are a preset's when every beam lies this close to the preset's; the
# parallax of KITTI's HDL-64E moves its medians up to 0.6 deg off the nominal elevations.
PRESET_TOLERANCE_DEG = 1.0


def sensor_from_elevations(name: str, elevations_deg: np.ndarray, width: int) -> SensorModel:
    """The sensor of beams measured in the data, (B,) elevations in degrees from the top beam
    (NaN = a beam without points): the preset with B beams within PRESET_TOLERANCE_DEG of them,
    else a model `name` with the measured elevations (gaps interpolated, made strictly descending)
    and `width` columns."""
    el = np.asarray(elevations_deg, dtype=np.float64)
    have = ~np.isnan(el)
    if have.sum() < 2:
        raise DataError(None, f"{name}: cannot measure beam elevations from {int(have.sum())} beams")
    for preset in PRESETS.values():
        nominal = np.asarray(preset.elevations_deg)
        if preset.n_rings == len(el) and np.nanmax(np.abs(el - nominal)) < PRESET_TOLERANCE_DEG:
            return preset
    idx = np.arange(len(el))
    el = np.interp(idx, idx[have], el[have])
    el = np.minimum.accumulate(el) - idx * 1e-6  # strictly descending
    return SensorModel(name, tuple(float(x) for x in el), width=max(8, int(width)))


def get_sensor(name: str) -> SensorModel:
    """A preset by name (`hdl32e`, `hdl64e`, `vlp16`), or an Ouster metadata json path."""
    if name in PRESETS:
        return PRESETS[name]
    path = Path(name)
    if path.suffix == ".json" and path.exists():
        return ouster_from_metadata(path)
    raise KeyError(f"unknown sensor {name!r}; presets: {', '.join(PRESETS)} or an Ouster metadata .json")


def ouster_from_metadata(path: str | Path) -> SensorModel:
    """Build a sensor model from an Ouster metadata json (legacy or v2+ layout)."""
    path = Path(path)
    try:
        meta = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise DataError(path, f"cannot read Ouster metadata: {exc}") from exc
    altitudes = meta.get("beam_altitude_angles") or meta.get("beam_intrinsics", {}).get("beam_altitude_angles")
    mode = meta.get("lidar_mode") or meta.get("config_params", {}).get("lidar_mode")
    product = meta.get("prod_line") or meta.get("sensor_info", {}).get("prod_line", "ouster")
    if not altitudes or not mode:
        raise DataError(path, "Ouster metadata lacks beam_altitude_angles or lidar_mode")
    cols, rate = (int(v) for v in str(mode).split("x"))
    el = np.asarray(altitudes, dtype=np.float64)
    # Ouster lists beams top-down already; enforce strict descent for degenerate duplicates.
    order = np.argsort(-el, kind="stable")
    el = el[order]
    el = el - np.arange(len(el)) * 1e-6
    return SensorModel(
        f"ouster-{product}".lower().replace(" ", "-"),
        tuple(float(x) for x in el),
        width=cols,
        frequency_hz=float(rate),
        min_range=0.3,
        max_range=200.0,
    )
