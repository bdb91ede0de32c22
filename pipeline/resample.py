"""Segment statistics and samples of a stored frame after its segments changed (a track split).

A frame artifact keeps the points, intensities and per-point segment ids, not the range image or
the height above ground; both are rebuilt here from the points alone (beam rows from the
points' elevations, the ground estimated again), then the changed segments go through the same
statistics, validity rule and sample rendering as at ingest (`pipeline.samples`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pipeline.config import PipelineConfig
from pipeline.ground import estimate_ground
from pipeline.range_image import elevation_rows, project
from pipeline.samples import SegmentTable, render_segments, segment_table
from pipeline.scan import Scan
from pipeline.sensors import SensorModel


@dataclass(frozen=True)
class ResampledSegments:
    """Statistics of the requested segments (all arrays of length K, in request order) and the
    samples of the valid ones.

    table: SegmentTable of the K segments; samples: (V, C, S, S) uint8; sample_of: (K,) int32
    row of each segment's sample in `samples`, -1 = invalid (no sample).
    """

    table: SegmentTable
    samples: np.ndarray
    sample_of: np.ndarray


def _scan_of(points: np.ndarray, intensity: np.ndarray, sensor: SensorModel) -> Scan:
    return Scan(points=points, intensity=intensity, ring=elevation_rows(points, sensor))


def height_above_ground(points: np.ndarray, intensity: np.ndarray, sensor: SensorModel, config: PipelineConfig) -> np.ndarray:
    """(N,) float32 metres above the ground estimated from the frame's (N, 3) lidar points."""
    scan = _scan_of(points, intensity, sensor)
    return estimate_ground(scan, project(scan, sensor, config.range_image), config.ground).height


def resample_segments(
    points: np.ndarray,
    intensity: np.ndarray,
    seg_point: np.ndarray,
    seg_ids: np.ndarray,
    sensor: SensorModel,
    config: PipelineConfig,
) -> ResampledSegments:
    """Statistics and samples of segments `seg_ids` (K,) of a frame: (N, 3) float32 lidar points,
    (N,) float32 intensity, (N,) int32 segment id per point (-1 = none)."""
    n = len(points)
    assert points.shape == (n, 3) and intensity.shape == (n,) and seg_point.shape == (n,)
    count = int(max(seg_point.max(initial=-1), seg_ids.max(initial=-1))) + 1
    full = segment_table(points, seg_point, count, config.samples)
    table = SegmentTable(
        n_points=full.n_points[seg_ids], centroid=full.centroid[seg_ids], range=full.range[seg_ids], valid=full.valid[seg_ids]
    )
    valid_ids = seg_ids[table.valid].astype(np.int32)
    sample_of = np.full(len(seg_ids), -1, np.int32)
    sample_of[table.valid] = np.arange(len(valid_ids), dtype=np.int32)
    if len(valid_ids) == 0:
        c = config.samples
        return ResampledSegments(table, np.zeros((0, c.channels, c.size, c.size), np.uint8), sample_of)
    scan = _scan_of(points, intensity, sensor)
    image = project(scan, sensor, config.range_image)
    height = estimate_ground(scan, image, config.ground).height
    samples = render_segments(scan, image, height, seg_point, full.centroid, valid_ids, sensor, config.samples)
    return ResampledSegments(table, samples, sample_of)
