"""Small hand-made FrameResults for the tests of the modules that consume them."""

from __future__ import annotations

import numpy as np

from pipeline.frames import FrameResult, FrameSegments
from pipeline.scan import Scan


def frame(index: int, segment: list[int], track_id: list[int], link_score: list[float], ground: list[bool] | None = None,
          fragments: list[tuple[int, int]] = (), share: list[float] = ()) -> FrameResult:
    """A frame whose points carry `segment` ids (-1 = none) and whose segments carry `track_id`
    (0 = invalid) and `link_score`; every valid segment has a sample (a canvas of its id)."""
    seg = np.asarray(segment, np.int32)
    n, s = len(seg), len(track_id)
    tid = np.asarray(track_id, np.int64)
    valid = tid > 0
    counts = np.bincount(seg[seg >= 0], minlength=s).astype(np.int32)
    centroid = np.stack([np.arange(s, dtype=np.float32), np.zeros(s, np.float32), np.zeros(s, np.float32)], 1)
    segments = FrameSegments(n_points=counts, centroid=centroid, range=np.ones(s, np.float32), valid=valid,
                             centroid_world=centroid.astype(np.float64) + index, track_id=tid,
                             link_score=np.asarray(link_score, np.float32))
    sample_segment = np.flatnonzero(valid).astype(np.int32)
    scan = Scan(points=np.zeros((n, 3), np.float32), intensity=np.zeros(n, np.float32), ring=np.zeros(n, np.int16))
    return FrameResult(
        index=index, name=f"{index:06d}", scan=scan, segment=seg,
        ground=np.zeros(n, bool) if ground is None else np.asarray(ground, bool),
        height=np.zeros(n, np.float32), seg_pixel=np.zeros((1, 1), np.int32), range_pixels=np.zeros((1, 1), np.float32),
        segments=segments, samples=np.stack([np.full((4, 2, 2), k, np.uint8) for k in sample_segment]).reshape(-1, 4, 2, 2),
        sample_segment=sample_segment, T_world_lidar=np.eye(4), time=0.1 * index,
        fragments=np.asarray(fragments, np.int32).reshape(-1, 2), fragment_share=np.asarray(share, np.float32),
    )
