"""`ingest`: run the perception pipeline over a registered sequence and store its results.

1. Roll back whatever an earlier, unfinished attempt wrote for the sequence (rows and artifacts).
2. Open the sequence as `tracklabel process` does (`pipeline.sequence.open_sequence`: sensor,
   width and poses, `file` or `icp`), and run `SequenceProcessor.iter_frames` in frame order.
3. Every `ingest_batch_frames` frames: the new tracks (one short transaction), the frames'
   artifact files (no lock held), then in one transaction the frames, segments, constraint pairs
   and track and stitch statistics (`app.crud.ingest_rows`). A frame row is visible only together
   with all its segments; a killed attempt leaves whole batches, which the next attempt (another
   worker, after the lease expires) rolls back and redoes.
4. Mark the sequence `ready`. Reviews need a ready sequence, so no operator work is lost by step 1.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from pydantic import ConfigDict, Field
from sqlalchemy.orm import Session

from app import crud
from app.artifacts import FrameArtifact
from app.crud.ingest_rows import IngestRows, begin_ingest, check_can_ingest, mark_failed, record_source
from app.data_roots import GuardedSource
from app.jobs.context import JobContext
from app.jobs.registry import JobType, register
from app.schemas import IngestPoses, JsonModel


class IngestParams(JsonModel):
    model_config = ConfigDict(extra="forbid")
    sequence_id: int = Field(ge=1, le=2**31 - 1)
    force: bool = False  # re-ingest a ready sequence (drops its reviews)
    poses: IngestPoses = "file"  # the sequence's own poses, or estimated (KISS-ICP)


def run_ingest(ctx: JobContext, params: IngestParams) -> dict[str, Any]:
    from pipeline import processing, sequence

    with ctx.db.write() as s:
        start = begin_ingest(s, params.sequence_id, ctx.job_id, params.force)
        s.commit()
    if isinstance(start, dict):
        return start  # done before a crash; idempotent
    path, fmt, overrides = start
    ctx.artifacts.remove_sequence(params.sequence_id)
    ctx.progress(0.0, "opening the sequence")

    # the files may have changed since registration: no link out of the data roots is read, and
    # each frame's files are checked again as they are read (app/data_roots.py)
    data_roots = crud.check_tree_inside_roots(Path(path), ctx.settings.data_roots)
    config = crud.pipeline_config(ctx.settings.pipeline_config, overrides)
    crud.check_sensor_file(config, ctx.settings.data_roots)
    opened = sequence.open_sequence(path, fmt, sensor=config.sensor.name, poses=params.poses)
    source = GuardedSource(opened.source, data_roots)
    with ctx.db.write() as s:
        record_source(s, params.sequence_id, source.format, opened.sensor.to_dict())
        s.commit()

    rows = IngestRows(params.sequence_id)
    skipped: list[str] = []
    processor = processing.SequenceProcessor(config, opened.sensor)
    frames = processor.iter_frames(source, workers=1, poses=opened.poses,
                                   on_skip=lambda i, err: skipped.append(f"frame {i}: {err}"))
    for batch in _batches(frames, ctx.settings.ingest_batch_frames, rows, skipped):
        _write_batch(ctx, rows, batch)
        ctx.progress(0.99 * (batch[-1].index + 1) / max(len(source), 1), f"frame {batch[-1].index + 1}/{len(source)}")
    ctx.checkpoint()

    with ctx.db.write() as s:
        rows.mark_ready(s)
        crud.analyze_tables(s)
        s.commit()
    crud.vacuum_after_bulk_load(ctx.db.engine)
    return {"sequence_id": params.sequence_id, "frames": rows.frames, "segments": rows.segments,
            "tracks": len(rows.tracks), "constraints": rows.constraints, "fragments": rows.fragments,
            "stitches": len(rows.stitches), "skipped": skipped, "linked": bool(processor.linked)}


def _batches(frames: Any, size: int, rows: IngestRows, skipped: list[str]) -> Any:
    """The frames in batches of `size`; an empty scan ends its batch and is skipped: an empty
    file is a truncated copy, never a scan, so it is reported like a corrupt frame, not stored as
    a frame with nothing to label."""
    batch: list[Any] = []
    for fr in frames:
        rows_in_file = fr.scan.input_rows
        if (len(fr.segment) if rows_in_file is None else len(rows_in_file)) == 0:
            if batch:
                yield batch
                batch = []
            skipped.append(f"frame {fr.index}: {fr.name}: empty scan file (0 points)")
            rows.gap()
            continue
        batch.append(fr)
        if len(batch) >= size:
            yield batch
            batch = []
    if batch:
        yield batch


def _write_batch(ctx: JobContext, rows: IngestRows, frames: list[Any]) -> None:
    """New tracks commit first (a short transaction), then the artifacts are compressed and written
    with no database lock held, then the frames, segments and pairs commit together: the API's
    writers never wait behind compression."""
    with ctx.db.write() as s:
        rows.insert_new_tracks(s, frames)
        s.commit()
    rels = [_write_artifact(ctx, rows, fr) for fr in frames]
    with ctx.db.write() as s:
        for fr, rel in zip(frames, rels, strict=True):
            rows.write_frame(s, fr, rel)
        rows.update_statistics(s)
        s.commit()


def _write_artifact(ctx: JobContext, rows: IngestRows, fr: Any) -> str:
    """The frame's artifact file (atomic rename); the row pointing at it commits later."""
    db_track = rows.db_tracks(fr)
    point_seg = np.asarray(fr.segment, dtype=np.int32)
    point_track = np.zeros(len(point_seg), np.int64)  # a frame without segments indexes nothing
    segmented = point_seg >= 0
    point_track[segmented] = db_track[point_seg[segmented]]
    return ctx.artifacts.write_frame(
        rows.sequence_id,
        fr.index,
        FrameArtifact(
            points=np.asarray(fr.scan.points, dtype=np.float32),
            intensity=np.asarray(fr.scan.intensity, dtype=np.float32),
            segment=point_seg,
            ground=np.asarray(fr.ground, dtype=bool),
            track=point_track,
            samples=np.asarray(fr.samples, dtype=np.uint8),
            sample_segment=np.asarray(fr.sample_segment, dtype=np.int32),
            input_rows=fr.scan.input_rows,
        ),
    )


def on_ingest_stop(ctx: JobContext, params: IngestParams, reason: str) -> None:
    """A failed or cancelled ingest leaves the sequence `failed` (its next ingest rolls back)."""
    with ctx.db.write() as s:
        mark_failed(s, params.sequence_id)
        s.commit()


def prepare_ingest(s: Session, params: IngestParams) -> None:
    """Checked when an ingest job is created (`crud.ingest_rows.check_can_ingest`)."""
    check_can_ingest(s, params.sequence_id, params.force)


register(
    JobType(
        name="ingest",
        params=IngestParams,
        handler=run_ingest,
        admin_only=True,
        description="Run segmentation and association over a registered sequence and store the tracks.",
        on_stop=on_ingest_stop,
        prepare=prepare_ingest,
    )
)
