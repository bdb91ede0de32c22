"""A fake perception pipeline: deterministic FrameResult-like frames, so that service tests need
neither real sequences nor the real pipeline's run time. `fake_pipeline(...)` puts it in place of
the pipeline functions the app calls (`pipeline.sequence.open_sequence`,
`pipeline.processing.SequenceProcessor`, `pipeline.resample`'s two) for the length of a `with`.

Object `o` (0-based) is visible in frames [o % 3, F) and is track key o + 1; each frame also has
one small segment that is not valid (no track) and `ground` ground points.
"""

from __future__ import annotations

import contextlib
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np

import pipeline.processing
import pipeline.resample
import pipeline.sequence
from pipeline.sensors import get_sensor

POINTS_PER_SEGMENT = 20
SAMPLE_SHAPE = (4, 8, 8)


@dataclass
class FakeSource:
    path: Path
    n_frames: int
    format: str = "fake"
    sensor: Any = None
    poses: Any = None
    times: Any = None

    def __len__(self) -> int:
        return self.n_frames

    def frame_name(self, index: int) -> str:
        return f"{index:06d}"


def fake_frame(index: int, n_objects: int, ground: int = 30, key_offset: int = 0) -> SimpleNamespace:
    objs = [o for o in range(n_objects) if o % 3 <= index]
    rng = np.random.default_rng(index)
    counts = [POINTS_PER_SEGMENT] * len(objs) + [4]  # + one invalid segment
    seg_of_point = np.concatenate([np.full(c, s, np.int32) for s, c in enumerate(counts)] + [np.full(ground, -1, np.int32)])
    n = len(seg_of_point)
    points = rng.normal(size=(n, 3)).astype(np.float32) * 5
    centroid = np.array([[o * 2.0, index * 0.1, 0.5] for o in objs] + [[0.0, 0.0, 0.0]], np.float32)
    track_id = np.array([key_offset + o + 1 for o in objs] + [0], np.int64)
    link = np.array([np.nan if index == o % 3 else 0.9 for o in objs] + [np.nan], np.float32)
    valid = np.array([True] * len(objs) + [False])
    samples = np.stack([np.full(SAMPLE_SHAPE, (index * 7 + s) % 256, np.uint8) for s in range(len(objs))])
    segments = SimpleNamespace(
        n_points=np.array(counts, np.int32),
        centroid=centroid,
        centroid_world=centroid.astype(np.float64),
        range=np.linalg.norm(centroid, axis=1).astype(np.float32),
        valid=valid,
        track_id=track_id,
        link_score=link,
    )
    return SimpleNamespace(
        index=index,
        name=f"{index:06d}",
        scan=SimpleNamespace(points=points, intensity=rng.random(n, dtype=np.float32), input_rows=None),
        segment=seg_of_point,
        ground=seg_of_point < 0,
        segments=segments,
        samples=samples.reshape(len(objs), *SAMPLE_SHAPE),
        sample_segment=np.arange(len(objs), dtype=np.int32),
        T_world_lidar=np.eye(4),
        time=index * 0.1,
        timings_ms={},
    )


class FakeProcessor:
    def __init__(self, n_objects: int, delay_s: float = 0.0, fail_at: int | None = None) -> None:
        self.n_objects = n_objects
        self.delay_s = delay_s
        self.fail_at = fail_at
        self.linked = True

    def iter_frames(self, source: FakeSource, **_: Any) -> Iterator[SimpleNamespace]:
        for i in range(len(source)):
            if self.fail_at is not None and i == self.fail_at:
                raise RuntimeError(f"fake pipeline failure at frame {i}")
            if self.delay_s:
                time.sleep(self.delay_s)
            yield fake_frame(i, self.n_objects)


class FakePipeline:
    """Opens any path as a FakeSource of `n_frames` frames (sensor: the hdl64e preset)."""

    def __init__(self, n_frames: int = 6, n_objects: int = 4, delay_s: float = 0.0, fail_at: int | None = None) -> None:
        self.n_frames, self.n_objects, self.delay_s, self.fail_at = n_frames, n_objects, delay_s, fail_at

    def open_sequence(self, path: Any, *_: Any, **__: Any) -> SimpleNamespace:
        return SimpleNamespace(source=FakeSource(Path(path), self.n_frames), sensor=get_sensor("hdl64e"), poses=None)

    def processor(self, config: Any, sensor: Any) -> FakeProcessor:
        return FakeProcessor(self.n_objects, self.delay_s, self.fail_at)

    def resample_segments(self, points: np.ndarray, intensity: np.ndarray, seg_point: np.ndarray, seg_ids: np.ndarray,
                          sensor: Any, config: Any) -> Any:
        """Statistics as the pipeline computes them; validity = more than FAKE_MIN_POINTS points;
        each sample filled with 100 + its segment id (so a test sees which ones were re-rendered)."""
        from pipeline.resample import ResampledSegments
        from pipeline.samples import SegmentTable

        n = np.array([int((seg_point == s).sum()) for s in seg_ids], np.int32)
        cen = np.array([points[seg_point == s].mean(axis=0) if k else np.zeros(3) for s, k in zip(seg_ids, n, strict=True)],
                       np.float32).reshape(-1, 3)
        valid = n > FAKE_MIN_POINTS
        sample_of = np.full(len(seg_ids), -1, np.int32)
        sample_of[valid] = np.arange(int(valid.sum()))
        samples = np.stack([np.full(SAMPLE_SHAPE, 100 + int(s), np.uint8) for s in seg_ids[valid]]) if valid.any() \
            else np.zeros((0, *SAMPLE_SHAPE), np.uint8)
        table = SegmentTable(n_points=n, centroid=cen, range=np.linalg.norm(cen, axis=1).astype(np.float32), valid=valid)
        return ResampledSegments(table=table, samples=samples, sample_of=sample_of)

    def height_above_ground(self, points: np.ndarray, intensity: np.ndarray, sensor: Any, config: Any) -> np.ndarray:
        """Height above a flat ground at z = FAKE_GROUND_Z."""
        return (points[:, 2] - FAKE_GROUND_Z).astype(np.float32)

    def install(self) -> None:
        """Put the fakes in place for good (a worker subprocess's job plugin)."""
        pipeline.sequence.open_sequence = self.open_sequence
        pipeline.processing.SequenceProcessor = self.processor
        pipeline.resample.resample_segments = self.resample_segments
        pipeline.resample.height_above_ground = self.height_above_ground


@contextlib.contextmanager
def fake_pipeline(fake: FakePipeline | None = None, **kw: Any) -> Iterator[FakePipeline]:
    """The fake pipeline in place inside the `with` (`fake`, else FakePipeline(**kw))."""
    fake = fake or FakePipeline(**kw)
    targets = [(pipeline.sequence, "open_sequence"), (pipeline.processing, "SequenceProcessor"),
               (pipeline.resample, "resample_segments"), (pipeline.resample, "height_above_ground")]
    before = [getattr(m, name) for m, name in targets]
    fake.install()
    try:
        yield fake
    finally:
        for (m, name), value in zip(targets, before, strict=True):
            setattr(m, name, value)


FAKE_MIN_POINTS = 3
FAKE_GROUND_Z = -20.0


def expected_counts(n_frames: int, n_objects: int) -> dict[str, int]:
    """Rows a fake ingest writes: frames, segments, tracks and constraint pairs."""
    seg = sum(sum(1 for o in range(n_objects) if o % 3 <= i) + 1 for i in range(n_frames))
    pairs = sum(max(0, n_frames - (o % 3) - 1) for o in range(n_objects))
    return {"frames": n_frames, "segments": seg, "tracks": n_objects, "constraints": pairs}
