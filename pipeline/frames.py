"""The frame container: everything the pipeline knows of one frame, from segmentation to tracks.

`processing.process_scan` fills the per-scan fields (steps 1-5); the association then adds the
pose, the time, the tracking fields of `segments` and the fragment links (`dataclasses.replace`),
so one type travels from the worker processes to every consumer (tracks.json, ingest, predict,
the experiments).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from pipeline.samples import SegmentTable
from pipeline.scan import Scan


@dataclass(frozen=True)
class FrameSegments(SegmentTable):
    """SegmentTable plus tracking, arrays of length S.

    centroid_world: (S, 3) float64 (lidar centroid when there are no poses);
    track_id: (S,) int64 global track id >= 1 for valid segments, 0 for the others;
    link_score: (S,) float32 score of the link to the previous frame, NaN where a track starts.
    """

    centroid_world: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros((0, 3)))
    track_id: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(0, np.int64))
    link_score: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(0, np.float32))


@dataclass(frozen=True)
class FrameResult:
    """Everything the pipeline knows of one frame.

    segment: (N,) int32 local segment id per point, -1 = ground / unsegmented.
    ground: (N,) bool; height: (N,) float32 metres above ground.
    seg_pixel: (H, W) int32 segment id per range-image pixel, -1 = none (valid segments only).
    range_pixels: (H, W) float32 range per pixel.
    segments: the segment table; its tracking fields are empty until the frame is associated.
    samples: (V, C, S, S) uint8 of the valid segments; sample_segment: (V,) int32 their segment ids.
    T_world_lidar: (4, 4) pose, None without poses (and before association); time: seconds.
    fragments: (E, 2) int32 (segment of this frame, segment of the previous frame) pairs of
    fragments of one object that are not track links (see `association.Links`); fragment_share: (E,).
    """

    index: int
    name: str
    scan: Scan
    segment: np.ndarray
    ground: np.ndarray
    height: np.ndarray
    seg_pixel: np.ndarray
    range_pixels: np.ndarray
    segments: FrameSegments
    samples: np.ndarray
    sample_segment: np.ndarray
    T_world_lidar: np.ndarray | None = None
    time: float = float("nan")
    timings_ms: dict[str, float] = dataclasses.field(default_factory=dict)
    fragments: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros((0, 2), np.int32))
    fragment_share: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(0, np.float32))

    def track_labels(self) -> np.ndarray:
        """(N,) uint32 track id per point: 0 for ground, unsegmented points and invalid segments."""
        out = np.zeros(len(self.segment), dtype=np.uint32)
        m = self.segment >= 0
        out[m] = self.segments.track_id[self.segment[m]].astype(np.uint32)
        return out
