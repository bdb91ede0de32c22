"""Velodyne `.pcap` recordings through velodyne-decoder (optional extra `tracklabel[velodyne]`).

velodyne-decoder is imported only when a recording is opened; its absence is a DataError. It
detects the model from the packets (HDL-64E calibration is read from the stream) and cuts one
scan per revolution. Opening decodes the file once to count the scans; `frame(i)` decodes again
from the start, or goes on from the previous call when frames are read in order.

Per scan: points in the sensor frame (x forward, y left, z up), intensity / 255, time relative to
the scan's first firing, and rows from the decoder's ring number (ring 0 is the lowest beam in
velodyne-decoder, so the direction is taken from the elevation). All returns of dual-return data
are kept. The sensor is the preset with the same beam count when its elevations match the data's
within 1 deg, else a model built from the first scan's per-ring elevations.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import numpy as np

from pipeline.errors import DataError
from pipeline.io.layout import measured_sensor
from pipeline.io.rings import rows_from_ring_field
from pipeline.scan import Scan, clean_rows, input_rows_of
from pipeline.sensors import SensorModel, get_sensor

INSTALL_HINT = "reading Velodyne pcaps needs the optional extra: pip install 'tracklabel[velodyne]'"
# velodyne_decoder.PointField order of the contiguous float arrays
X, Y, Z, INTENSITY, TIME, COLUMN, RING = range(7)


def _decoder():  # -> the velodyne_decoder module, or None
    try:
        import velodyne_decoder
    except ImportError:
        return None
    return velodyne_decoder


def sensor_for_scan(points: np.ndarray, ring: np.ndarray) -> SensorModel:
    """The preset matching a decoded scan's beams (N, 3 points; N ring numbers), else an estimate."""
    n = int(ring.max()) + 1 if len(ring) else 0
    if n < 2:
        raise DataError(None, "first Velodyne scan has fewer than two rings")
    return measured_sensor(f"velodyne-{n}beam", points, rows_from_ring_field(points, ring, n), n)


class VelodynePcapSequence:
    """A Velodyne pcap as a `pipeline.scan.SequenceSource` (no poses)."""

    format = "velodyne_pcap"

    def __init__(self, path: str | Path, sensor: str | SensorModel = "auto") -> None:
        self.path = Path(path)
        if not self.path.is_file():
            raise DataError(self.path, "no such pcap file")
        self._vd = _decoder()
        if self._vd is None:
            raise DataError(self.path, INSTALL_HINT)
        self.poses: np.ndarray | None = None
        self._iter: Iterator[tuple[float, np.ndarray]] | None = None
        self._next = 0
        stamps: list[float] = []
        first: np.ndarray | None = None
        for stamp, cloud in self._scans():
            stamps.append(stamp)
            first = cloud if first is None else first
        if first is None:
            raise DataError(self.path, "no Velodyne scan decoded (not Velodyne data?)")
        self.times = np.asarray(stamps, dtype=np.float64)
        self.sensor_from = "user flag" if isinstance(sensor, SensorModel) or sensor != "auto" else "ring field"
        if isinstance(sensor, SensorModel):
            self.sensor = sensor
        elif sensor != "auto":
            self.sensor = get_sensor(sensor)
        else:
            try:
                self.sensor = sensor_for_scan(first[:, :3], first[:, RING].astype(np.int64))
            except DataError as exc:
                raise DataError(self.path, exc.detail) from None

    def _scans(self) -> Iterator[tuple[float, np.ndarray]]:
        """(device time s, (N, 8) float32 decoded points) per scan, from the start of the file."""
        vd = self._vd
        try:
            for result in vd.read_pcap(str(self.path), vd.Config()):
                yield float(result.stamp.device), np.asarray(result.points, dtype=np.float32)
        except DataError:
            raise
        except Exception as exc:  # dpkt and the decoder raise many types on bad input
            raise DataError(self.path, f"cannot decode: {exc}") from None

    def __len__(self) -> int:
        return len(self.times)

    def frame_name(self, index: int) -> str:
        return f"{index:06d}"

    def _decoded(self, index: int) -> np.ndarray:
        if not 0 <= index < len(self):
            raise IndexError(f"frame {index} out of range for {len(self)} frames")
        if self._iter is None or index < self._next:
            self._iter, self._next = self._scans(), 0
        for _ in range(index - self._next):
            next(self._iter)
        _, cloud = next(self._iter)
        self._next = index + 1
        return cloud

    def frame(self, index: int) -> Scan:
        cloud = self._decoded(index)
        finite, dropped = clean_rows(cloud[:, [X, Y, Z, INTENSITY, TIME]])
        cloud = cloud[finite]
        points = np.ascontiguousarray(cloud[:, :3])
        t = cloud[:, TIME].astype(np.float64)
        return Scan(
            points=points,
            intensity=np.clip(cloud[:, INTENSITY] / 255.0, 0.0, 1.0).astype(np.float32),
            ring=rows_from_ring_field(points, cloud[:, RING].astype(np.int64), self.sensor.n_rings),
            time=(t - t.min()).astype(np.float32) if len(t) else t.astype(np.float32),
            dropped=dropped,
            input_rows=input_rows_of(finite),
        )
