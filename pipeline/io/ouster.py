"""Ouster recordings: a `.pcap` with its metadata `.json`, or an `.osf`, through ouster-sdk.

ouster-sdk is the optional extra `tracklabel[ouster]`; it is imported only when a recording is
opened, and its absence is a DataError. Metadata for a pcap: the `sensor_info` argument, else the
`.json` of the same stem, else the `.json` in the same folder whose stem is the longest prefix of
the pcap's (`OS-1-128_..._1024x10.json` for `OS-1-128_..._1024x10_lb_n3.pcap`).

Each frame is the staggered `LidarScan` of sensor 0 (the first in a multi-sensor file). Its input
rows are the H x W pixels row by row; points are the pixels with a return (range > 0) in the
sensor frame (x forward, y left, z up); `ring` is the pixel row ordered by beam altitude (Ouster rows already run top-down),
intensity the calibrated reflectivity / 255, time the column timestamp relative to the first
valid column.
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np

from pipeline.errors import DataError
from pipeline.scan import Scan, input_rows_of
from pipeline.sensors import SensorModel, get_sensor, ouster_from_metadata

INSTALL_HINT = "reading Ouster recordings needs the optional extra: pip install 'tracklabel[ouster]'"


def find_ouster_metadata(pcap: str | Path) -> Path | None:
    """The metadata json of an Ouster pcap (same stem, else the longest-prefix stem), or None."""
    pcap = Path(pcap)
    same = pcap.with_suffix(".json")
    if same.is_file():
        return same
    best: Path | None = None
    for cand in pcap.parent.glob("*.json"):
        if pcap.stem.startswith(cand.stem) and (best is None or len(cand.stem) > len(best.stem)):
            best = cand
    return best


def _recording(path: Path) -> Path:
    """The one .pcap or .osf a path names (a folder must hold exactly one)."""
    if path.is_file():
        if path.suffix.lower() not in (".pcap", ".osf"):
            raise DataError(path, "not an Ouster .pcap or .osf file")
        return path
    if not path.is_dir():
        raise DataError(path, "no such file or folder")
    found = sorted([*path.glob("*.pcap"), *path.glob("*.osf")])
    if len(found) != 1:
        raise DataError(path, f"holds {len(found)} .pcap/.osf recordings; open one file")
    return found[0]


def _sdk():  # -> the ouster.sdk modules (open_source, core)
    try:
        from ouster.sdk import core, open_source
    except ImportError:
        return None
    return open_source, core


class OusterSequence:
    """An Ouster pcap or osf as a `pipeline.scan.SequenceSource` (no poses)."""

    format = "ouster"

    def __init__(
        self,
        path: str | Path,
        sensor: str | SensorModel = "auto",
        sensor_info: str | Path | None = None,
    ) -> None:
        self.path = Path(path)
        self.recording = _recording(self.path)
        sdk = _sdk()
        if sdk is None:
            raise DataError(self.recording, INSTALL_HINT)
        open_source, core = sdk
        self._core = core
        self.metadata: Path | None = None
        kwargs: dict[str, object] = {}
        if self.recording.suffix.lower() == ".pcap":
            self.metadata = Path(sensor_info) if sensor_info else find_ouster_metadata(self.recording)
            if self.metadata is None or not self.metadata.is_file():
                raise DataError(self.recording, "no Ouster metadata .json beside it (pass sensor_info=)")
            kwargs = {"meta": [str(self.metadata)], "index": True}
        try:
            self._source = open_source(str(self.recording), sensor_idx=0, **kwargs)
            self._info = self._source.sensor_info[0]
            count = len(self._source)
        except Exception as exc:  # the SDK raises its own exception types
            raise DataError(self.recording, f"cannot open with ouster-sdk: {exc}") from None
        if count == 0:
            raise DataError(self.recording, "no complete scan decoded (does the metadata match the data?)")
        self._count = count
        self._lut = core.XYZLut(self._info, use_extrinsics=False)
        altitudes = np.asarray(self._info.beam_altitude_angles, dtype=np.float64)
        order = np.argsort(-altitudes, kind="stable")
        self._row_of_pixel_row = np.empty(len(order), dtype=np.int16)
        self._row_of_pixel_row[order] = np.arange(len(order), dtype=np.int16)
        self.sensor_from = "metadata" if sensor == "auto" else "user flag"
        if isinstance(sensor, SensorModel):
            self.sensor = sensor
        elif sensor != "auto":
            self.sensor = get_sensor(sensor)
        else:
            self.sensor = self._metadata_sensor()
        self.poses: np.ndarray | None = None
        self._times: np.ndarray | None = None

    def _metadata_sensor(self) -> SensorModel:
        if self.metadata is not None:
            return ouster_from_metadata(self.metadata)
        with tempfile.TemporaryDirectory() as tmp:  # an osf embeds its metadata
            meta = Path(tmp) / "metadata.json"
            meta.write_text(self._info.to_json_string())
            return ouster_from_metadata(meta)

    @property
    def times(self) -> np.ndarray:
        """(F,) float64 seconds: each scan's first valid column timestamp (decodes every scan once)."""
        if self._times is None:
            self._times = np.array([self._first_stamp(self._scan(i)) * 1e-9 for i in range(len(self))])
        return self._times

    def __len__(self) -> int:
        return self._count

    def frame_name(self, index: int) -> str:
        return f"{index:06d}"

    def _scan(self, index: int):  # -> ouster.sdk.core.LidarScan
        if not 0 <= index < len(self):
            raise IndexError(f"frame {index} out of range for {len(self)} frames")
        try:
            return self._source[index][0]
        except Exception as exc:
            raise DataError(self.recording, f"frame {index}: cannot decode: {exc}") from None

    @staticmethod
    def _first_stamp(scan) -> int:
        ts = np.asarray(scan.timestamp)
        valid = ts[ts > 0]
        return int(valid.min()) if len(valid) else 0

    def frame(self, index: int) -> Scan:
        scan = self._scan(index)
        core = self._core
        xyz = np.asarray(self._lut(scan))  # (H, W, 3) float64, staggered
        rng = np.asarray(scan.field(core.ChanField.RANGE))  # (H, W)
        h, w = rng.shape
        hit = rng > 0
        if core.ChanField.REFLECTIVITY in scan.fields:
            inten = np.asarray(scan.field(core.ChanField.REFLECTIVITY), dtype=np.float64) / 255.0
        else:
            inten = np.zeros((h, w))
        stamps = np.asarray(scan.timestamp, dtype=np.int64)  # (W,) ns
        t0 = self._first_stamp(scan)
        col_time = np.where(stamps > 0, (stamps - t0) * 1e-9, 0.0)
        rows = np.broadcast_to(self._row_of_pixel_row[:h, None], (h, w))
        finite = np.isfinite(xyz).all(axis=2)
        kept = hit & finite
        return Scan(
            points=xyz[kept].astype(np.float32),
            intensity=np.clip(inten[kept], 0.0, 1.0).astype(np.float32),
            ring=rows[kept].astype(np.int16),
            time=np.broadcast_to(col_time[None, :], (h, w))[kept].astype(np.float32),
            dropped=int((hit & ~finite).sum()),
            input_rows=input_rows_of(kept.ravel()),
        )

    def close(self) -> None:
        self._source.close()
