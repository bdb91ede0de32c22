"""An in-memory SequenceSource for tests."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from pipeline.errors import DataError
from pipeline.scan import Scan
from pipeline.sensors import SensorModel


class MemorySource:
    """Frames given as Scans (or DataError to simulate a corrupt frame), with optional poses."""

    format = "memory"

    def __init__(self, scans: list[Scan | DataError], sensor: SensorModel, poses: np.ndarray | None = None):
        self.path = Path("memory")
        self.scans = scans
        self.sensor = sensor
        self.sensor_from = "user flag"
        self.poses = poses
        self.times = None

    def __len__(self) -> int:
        return len(self.scans)

    def frame(self, index: int) -> Scan:
        s = self.scans[index]
        if isinstance(s, DataError):
            raise s
        return s

    def frame_name(self, index: int) -> str:
        return f"{index:06d}"
