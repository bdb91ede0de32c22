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
from sqlalchemy import select, update
from sqlalchemy.orm import Session

from app import crud
from app.artifacts import FrameArtifact
from app.core.errors import Conflict, NotFound
from app.crud.ingest_rows import IngestRows
from app.data_roots import GuardedSource
from app.jobs.context import JobContext
from app.jobs.registry import JobType, register
from app.models import Job, Sequence
from app.schemas import IngestPoses, JsonModel


class IngestParams(JsonModel):
    model_config = ConfigDict(extra="forbid")
    sequence_id: int = Field(ge=1, le=2**31 - 1)
    force: bool = False  # re-ingest a ready sequence (drops its reviews)
    poses: IngestPoses = "file"  # the sequence's own poses, or estimated (KISS-ICP)


def run_ingest(ctx: JobContext, params: IngestParams) -> dict[str, Any]:
    from pipeline import processing, sequence

    with ctx.db.write() as s:
        seq = s.get(Sequence, params.sequence_id)
        if seq is None:
            raise NotFound(f"sequence {params.sequence_id} not found")
        if seq.status == "ready" and seq.ingest_job_id == ctx.job_id:
            return {"sequence_id": seq.id, **crud.sequence_stats(s, seq)}  # done before a crash; idempotent
        if seq.status == "ready" and not params.force:
            raise Conflict(f"sequence {seq.id} is already ingested; pass force=true to redo it")
        crud.clear_sequence_rows(s, seq.id)
        seq.status, seq.n_frames, seq.ingest_job_id = "ingesting", 0, ctx.job_id
        path, fmt, overrides = seq.path, seq.format, seq.config
        s.commit()
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
        s.execute(update(Sequence).where(Sequence.id == params.sequence_id)
                  .values(format=source.format, sensor=opened.sensor.to_dict()))
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
        s.execute(update(Sequence).where(Sequence.id == params.sequence_id).values(status="failed"))
        s.commit()


def active_ingest_job(s: Session, sequence_id: int) -> int | None:
    """The id of a queued or running ingest job of a sequence, if any."""
    for job_id, params in s.execute(
        select(Job.id, Job.params).where(Job.type == "ingest", Job.status.in_(("queued", "running")))
    ).all():
        if isinstance(params, dict) and params.get("sequence_id") == sequence_id:
            return int(job_id)
    return None


def note_queued(s: Session, sequence_id: int, job_id: int) -> None:
    """Point a sequence that is not ingested yet at its queued ingest job (`ingest_job_id`).

    A ready sequence keeps the id of the job that made it until the forced re-ingest starts:
    `run_ingest` reads "ready with my job id" as "I finished before a crash" and returns at once,
    so pointing a ready sequence at a queued job would turn `force` into a no-op."""
    seq = s.get(Sequence, sequence_id)
    if seq is not None and seq.status != "ready":
        seq.ingest_job_id = job_id


def prepare_ingest(s: Session, params: IngestParams) -> None:
    """Checked when an ingest job is created: the sequence exists, is not being ingested already,
    and is not ready unless `force`."""
    seq = s.get(Sequence, params.sequence_id)
    if seq is None:
        raise NotFound(f"sequence {params.sequence_id} not found")
    active = active_ingest_job(s, params.sequence_id)
    if active is not None:
        raise Conflict(f"sequence {params.sequence_id} already has ingest job {active}")
    if seq.status == "ready" and not params.force:
        raise Conflict(f"sequence {params.sequence_id} is already ingested; pass force=true to redo it")


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
