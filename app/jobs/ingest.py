"""`ingest`: run the perception pipeline over a registered sequence and store its results.

1. Roll back whatever an earlier, unfinished attempt wrote for the sequence (rows and artifacts).
2. Open the sequence as `tracklabel process` does (`pipeline.sequence.open_sequence`: sensor,
   width and poses, `file` or `icp`), and run `SequenceProcessor.iter_frames` in frame order.
3. Every `ingest_batch_frames` frames: the new tracks (one short transaction), the frames'
   artifact files (no lock held), then in one transaction the frames, segments, constraint pairs
   (track links, and the fragment links that join two tracks into a stitch) and track and
   stitch statistics. A frame row is visible only together with all its segments; a killed attempt leaves whole
   batches, which the next attempt (another worker, after the lease expires) rolls back and redoes.
4. Mark the sequence `ready`. Reviews need a ready sequence, so no operator work is lost by step 1.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

import numpy as np
from pydantic import ConfigDict, Field
from sqlalchemy import case, insert, select, update
from sqlalchemy.orm import Session

from app import crud
from app.artifacts import FrameArtifact
from app.core.errors import Conflict, NotFound
from app.data_roots import GuardedSource
from app.jobs.context import JobContext
from app.jobs.registry import JobType, register
from app.models import Frame, Job, PairConstraint, Segment, Sequence, Stitch, Track, utcnow
from app.schemas import IngestPoses, JsonModel


class IngestParams(JsonModel):
    model_config = ConfigDict(extra="forbid")
    sequence_id: int = Field(ge=1, le=2**31 - 1)
    force: bool = False  # re-ingest a ready sequence (drops its reviews)
    poses: IngestPoses = "file"  # the sequence's own poses, or estimated (KISS-ICP)


class FrameProcessor(Protocol):
    def iter_frames(self, source: Any, **kwargs: Any) -> Iterator[Any]: ...


class IngestBackend:
    """How ingest opens a sequence and builds the processor (tests substitute a fake)."""

    def open(self, path: str, fmt: str, sensor: str, poses: str) -> Any:
        """A `pipeline.sequence.Sequence` (source, sensor, poses)."""
        from pipeline.sequence import open_sequence

        return open_sequence(path, fmt, sensor=sensor, poses=poses)

    def processor(self, config: Any, sensor: Any) -> FrameProcessor:
        from pipeline.processing import SequenceProcessor

        return SequenceProcessor(config, sensor)

    def config(self, settings_path: Path | None, overrides: dict[str, Any] | None) -> Any:
        from pipeline.config import load_config

        cfg = load_config(settings_path)
        return cfg.override(overrides) if overrides else cfg


    def resample(
        self, sensor: dict[str, Any] | None, config: Any, points: np.ndarray, intensity: np.ndarray,
        seg_point: np.ndarray, seg_ids: np.ndarray,
    ) -> Any:
        """Statistics and samples of segments `seg_ids` of a stored frame whose segments changed
        (a track split): a `pipeline.resample.ResampledSegments`."""
        from pipeline.resample import resample_segments

        return resample_segments(points, intensity, seg_point, seg_ids, _sensor_model(sensor), config)

    def height(self, sensor: dict[str, Any] | None, config: Any, points: np.ndarray, intensity: np.ndarray) -> np.ndarray:
        """(N,) float32 height above ground of a stored frame's points (split by height)."""
        from pipeline.resample import height_above_ground

        return height_above_ground(points, intensity, _sensor_model(sensor), config)


def _sensor_model(sensor: dict[str, Any] | None) -> Any:
    from pipeline.sensors import SensorModel

    if sensor is None:
        raise Conflict("the sequence has no sensor model recorded (ingested before sensors were stored); ingest it again")
    return SensorModel.from_dict(sensor)


_backend: IngestBackend = IngestBackend()


def get_backend() -> IngestBackend:
    """How sequences are opened and samples rendered now (the track repair uses it too)."""
    return _backend


def set_backend(backend: IngestBackend) -> None:
    """Replace how sequences are opened and processed (tests and plugins)."""
    global _backend
    _backend = backend


@dataclass
class _TrackAcc:
    """Running statistics of one track during ingest."""

    db_id: int
    first: int
    last: int
    length: int = 0
    n_samples: int = 0
    n_points: int = 0
    range_sum: float = 0.0
    last_segment_id: int | None = None


@dataclass
class _StitchAcc:
    """Running statistics of one stitch during ingest."""

    db_id: int
    links: int = 0
    share: float = 0.0


@dataclass
class _IngestState:
    sequence_id: int
    tracks: dict[int, _TrackAcc] = field(default_factory=dict)
    stitches: dict[tuple[int, int], _StitchAcc] = field(default_factory=dict)  # (track a, track b) db ids
    frames: int = 0
    segments: int = 0
    constraints: int = 0
    fragments: int = 0
    skipped: list[str] = field(default_factory=list)
    # the previous frame's segment rows and their tracks (fragment links point at them)
    prev_seg_ids: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    prev_db_track: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))


def run_ingest(ctx: JobContext, params: IngestParams) -> dict[str, Any]:
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
    config = _backend.config(ctx.settings.pipeline_config, overrides)
    crud.check_sensor_file(config, ctx.settings.data_roots)
    opened = _backend.open(path, fmt, getattr(getattr(config, "sensor", None), "name", "auto"), params.poses)
    source, sensor = GuardedSource(opened.source, data_roots), opened.sensor
    total = len(source)
    with ctx.db.write() as s:
        s.execute(
            update(Sequence)
            .where(Sequence.id == params.sequence_id)
            .values(format=getattr(source, "format", fmt), sensor=_sensor_dict(sensor))
        )
        s.commit()

    state = _IngestState(params.sequence_id)
    processor = _backend.processor(config, sensor)

    def on_skip(index: int, error: Exception) -> None:
        state.skipped.append(f"frame {index}: {error}")

    batch: list[Any] = []
    for fr in processor.iter_frames(source, workers=1, poses=opened.poses, on_skip=on_skip):
        if _input_row_count(fr) == 0:
            # an empty file is a truncated copy, never a scan: skipped and reported like a corrupt
            # frame, not stored as a frame with nothing to label
            if batch:
                _write_batch(ctx, state, batch)
                batch = []
            on_skip(int(fr.index), ValueError(f"{fr.name}: empty scan file (0 points)"))
            state.prev_seg_ids, state.prev_db_track = np.zeros(0, np.int64), np.zeros(0, np.int64)
            continue
        batch.append(fr)
        if len(batch) >= ctx.settings.ingest_batch_frames:
            _write_batch(ctx, state, batch)
            batch = []
            ctx.progress(0.99 * (fr.index + 1) / max(total, 1), f"frame {fr.index + 1}/{total}")
    if batch:
        _write_batch(ctx, state, batch)
    ctx.checkpoint()

    with ctx.db.write() as s:
        top = max(state.tracks, default=0)  # the split's key counter starts above every ingested key
        s.execute(
            update(Sequence).where(Sequence.id == params.sequence_id).values(
                status="ready", n_frames=state.frames,
                last_track_key=case((Sequence.last_track_key >= top, Sequence.last_track_key), else_=top))
        )
        crud.analyze_tables(s)
        s.commit()
    crud.vacuum_after_bulk_load(ctx.db.engine)
    return {
        "sequence_id": params.sequence_id,
        "frames": state.frames,
        "segments": state.segments,
        "tracks": len(state.tracks),
        "constraints": state.constraints,
        "fragments": state.fragments,
        "stitches": len(state.stitches),
        "skipped": state.skipped,
        "linked": bool(getattr(processor, "linked", True)),
    }


def _input_row_count(fr: Any) -> int:
    """Rows the frame's file held (points plus dropped rows; `Scan.input_rows` masks them)."""
    rows = getattr(getattr(fr, "scan", None), "input_rows", None)
    return len(fr.segment) if rows is None else len(rows)


def _sensor_dict(sensor: Any) -> dict[str, Any] | None:
    to_dict = getattr(sensor, "to_dict", None)
    return to_dict() if callable(to_dict) else None


def _write_batch(ctx: JobContext, state: _IngestState, frames: list[Any]) -> None:
    """Write a batch of FrameResults (see the module docstring).

    New tracks commit first (a short transaction), then the artifacts are compressed and written
    with no database lock held, then the frames, segments and pairs commit together: the API's
    writers never wait behind compression.
    """
    with ctx.db.write() as s:
        _insert_new_tracks(s, state, frames)
        s.commit()
    rels = [_write_artifact(ctx, state, fr) for fr in frames]
    with ctx.db.write() as s:
        touched: set[int] = set()
        stitched: set[tuple[int, int]] = set()
        for fr, rel in zip(frames, rels, strict=True):
            _write_frame(s, state, fr, rel, touched, stitched)
        if stitched:
            s.execute(
                update(Stitch),
                [{"id": state.stitches[k].db_id, "links": state.stitches[k].links, "share": state.stitches[k].share}
                 for k in sorted(stitched)],
            )
        if touched:
            s.execute(
                update(Track),
                [
                    {
                        "id": state.tracks[k].db_id,
                        "last_frame": state.tracks[k].last,
                        "keep_end": state.tracks[k].last,
                        "length": state.tracks[k].length,
                        "n_samples": state.tracks[k].n_samples,
                        "n_points": state.tracks[k].n_points,
                        "priority": crud.queue_priority(state.tracks[k].n_points, None),
                        "mean_range": state.tracks[k].range_sum / max(state.tracks[k].length, 1),
                    }
                    for k in sorted(touched)
                ],
            )
        s.commit()


def _insert_new_tracks(s: Session, state: _IngestState, frames: Iterable[Any]) -> None:
    first_seen: dict[int, int] = {}
    for fr in frames:
        for key in np.unique(fr.segments.track_id):
            k = int(key)
            if k > 0 and k not in state.tracks and k not in first_seen:
                first_seen[k] = fr.index
    if not first_seen:
        return
    rows = [
        {
            "sequence_id": state.sequence_id,
            "key": k,
            "status": "pending",
            "first_frame": f,
            "last_frame": f,
            "keep_start": f,
            "keep_end": f,
            "length": 0,
            "n_samples": 0,
            "n_points": 0,
            "mean_range": 0.0,
            "version": 1,
            "updated_at": utcnow(),
        }
        for k, f in first_seen.items()
    ]
    # plain executemany, then read the ids back (bulk RETURNING in order goes row by row on SQLite)
    s.execute(insert(Track), rows)
    keys = list(first_seen)
    result = []
    for i in range(0, len(keys), 5000):
        result += s.execute(
            select(Track.id, Track.key).where(Track.sequence_id == state.sequence_id, Track.key.in_(keys[i : i + 5000]))
        ).all()
    for db_id, key in result:
        state.tracks[int(key)] = _TrackAcc(db_id=int(db_id), first=first_seen[int(key)], last=first_seen[int(key)])


def _db_tracks(state: _IngestState, fr: Any) -> np.ndarray:
    """(S,) int64 database track id of each segment of a frame, 0 = none."""
    keys = np.asarray(fr.segments.track_id, dtype=np.int64)
    db_track = np.zeros(len(keys), np.int64)
    for i in np.flatnonzero(keys > 0):
        db_track[i] = state.tracks[int(keys[i])].db_id
    return db_track


def _write_artifact(ctx: JobContext, state: _IngestState, fr: Any) -> str:
    """The frame's artifact file (atomic rename); the row pointing at it commits later."""
    db_track = _db_tracks(state, fr)
    point_seg = np.asarray(fr.segment, dtype=np.int32)
    point_track = np.zeros(len(point_seg), np.int64)  # a frame without segments indexes nothing
    segmented = point_seg >= 0
    point_track[segmented] = db_track[point_seg[segmented]]
    return ctx.artifacts.write_frame(
        state.sequence_id,
        fr.index,
        FrameArtifact(
            points=np.asarray(fr.scan.points, dtype=np.float32),
            intensity=np.asarray(fr.scan.intensity, dtype=np.float32),
            segment=point_seg,
            ground=np.asarray(fr.ground, dtype=bool),
            track=point_track,
            samples=np.asarray(fr.samples, dtype=np.uint8),
            sample_segment=np.asarray(fr.sample_segment, dtype=np.int32),
            input_rows=getattr(fr.scan, "input_rows", None),
        ),
    )


def _write_frame(
    s: Session, state: _IngestState, fr: Any, rel: str, touched: set[int], stitched: set[tuple[int, int]]
) -> None:
    """The frame's row, its segments' rows, the must-link pairs of its tracks and its fragment
    links; `touched` / `stitched` collect the tracks and stitches whose statistics changed."""
    n_seg = len(fr.segments.n_points)
    sample_index = np.full(n_seg, -1, np.int64)
    sample_index[np.asarray(fr.sample_segment, dtype=np.int64)] = np.arange(len(fr.sample_segment))
    db_track = _db_tracks(state, fr)
    frame_id = _insert_frame(s, state, fr, rel)
    state.frames += 1
    if n_seg == 0:
        state.prev_seg_ids, state.prev_db_track = np.zeros(0, np.int64), np.zeros(0, np.int64)
        return
    seg_ids = _insert_segments(s, state, fr, frame_id, db_track, sample_index)
    state.segments += n_seg
    pairs = _extend_tracks(state, fr, seg_ids, sample_index, touched)
    if pairs:
        s.execute(insert(PairConstraint), pairs)
        state.constraints += len(pairs)
    _write_fragments(s, state, fr, seg_ids, db_track, sample_index, stitched)
    state.prev_seg_ids, state.prev_db_track = seg_ids, db_track


def _insert_frame(s: Session, state: _IngestState, fr: Any, rel: str) -> int:
    """Insert the frame's row; its id."""
    pose = getattr(fr, "T_world_lidar", None)
    return s.execute(
        insert(Frame).returning(Frame.id),
        [
            {
                "sequence_id": state.sequence_id,
                "index": int(fr.index),
                "name": str(fr.name),
                "n_points": len(fr.segment),
                "n_segments": len(fr.segments.n_points),
                "n_samples": len(fr.sample_segment),
                "artifact": rel,
                "timestamp": _finite(getattr(fr, "time", None)),
                "pose": None if pose is None else [float(v) for v in np.asarray(pose).reshape(-1)],
            }
        ],
    ).scalar_one()


def _insert_segments(
    s: Session, state: _IngestState, fr: Any, frame_id: int, db_track: np.ndarray, sample_index: np.ndarray
) -> np.ndarray:
    """Insert a row per segment of the frame; (S,) int64 their ids by local segment id."""
    seg = fr.segments
    n_seg = len(seg.n_points)
    cen, cw = np.asarray(seg.centroid, np.float64), np.asarray(seg.centroid_world, np.float64)
    rows = [
        {
            "sequence_id": state.sequence_id,
            "frame_id": frame_id,
            "frame_index": int(fr.index),
            "local_id": i,
            "track_id": int(db_track[i]) or None,
            "n_points": int(seg.n_points[i]),
            "cx": float(cen[i, 0]),
            "cy": float(cen[i, 1]),
            "cz": float(cen[i, 2]),
            "wx": float(cw[i, 0]),
            "wy": float(cw[i, 1]),
            "wz": float(cw[i, 2]),
            "range": float(seg.range[i]),
            "valid": bool(seg.valid[i]),
            "link_score": _finite(seg.link_score[i]),
            "sample_index": int(sample_index[i]) if sample_index[i] >= 0 else None,
        }
        for i in range(n_seg)
    ]
    s.execute(insert(Segment), rows)
    seg_ids = np.zeros(n_seg, np.int64)
    for seg_id, local_id in s.execute(select(Segment.id, Segment.local_id).where(Segment.frame_id == frame_id)).all():
        seg_ids[local_id] = seg_id
    return seg_ids


def _extend_tracks(
    state: _IngestState, fr: Any, seg_ids: np.ndarray, sample_index: np.ndarray, touched: set[int]
) -> list[dict[str, Any]]:
    """Add the frame's segments to their tracks' running statistics; the must-link pair rows from
    each track's last sampled segment to this frame's (segments without a sample hold none)."""
    seg = fr.segments
    keys = np.asarray(seg.track_id, dtype=np.int64)
    pairs = []
    for i in np.flatnonzero(keys > 0):
        acc = state.tracks[int(keys[i])]
        prev_id = acc.last_segment_id
        sampled = bool(seg.valid[i]) and sample_index[i] >= 0
        if prev_id is not None and sampled:
            score = _finite(seg.link_score[i])
            pairs.append(
                {
                    "sequence_id": state.sequence_id,
                    "track_id": acc.db_id,
                    "segment_a_id": prev_id,
                    "segment_b_id": int(seg_ids[i]),
                    "score": 0.0 if score is None else score,
                    "kind": "must_link",
                }
            )
        if sampled:
            acc.last_segment_id = int(seg_ids[i])
            acc.n_samples += 1
        acc.last = int(fr.index)
        acc.length += 1
        acc.n_points += int(seg.n_points[i])
        acc.range_sum += float(seg.range[i])
        touched.add(int(keys[i]))
    return pairs


def _write_fragments(
    s: Session,
    state: _IngestState,
    fr: Any,
    seg_ids: np.ndarray,
    db_track: np.ndarray,
    sample_index: np.ndarray,
    stitched: set[tuple[int, int]],
) -> None:
    """The frame's fragment links (this frame's segment, previous frame's segment) between two
    different tracks: a stitch row per new track pair, a `fragment` constraint row per link."""
    from pipeline.tracks import fragment_track_pairs

    frag = getattr(fr, "fragments", None)
    if frag is None or len(frag) == 0 or len(state.prev_seg_ids) == 0:
        return
    # segments without a sample hold no constraint: their track is "none" here
    db_track = np.where(sample_index >= 0, db_track, 0)
    frag, pairs, share = fragment_track_pairs(frag, fr.fragment_share, db_track, state.prev_db_track)
    if len(frag) == 0:
        return
    keys = [(int(a), int(b)) for a, b in pairs]
    ta = db_track[frag[:, 0]]
    new = sorted({k for k in keys if k not in state.stitches})
    if new:
        s.execute(insert(Stitch), [{"sequence_id": state.sequence_id, "track_a_id": a, "track_b_id": b,
                                    "links": 0, "share": 0.0, "status": "pending", "version": 1} for a, b in new])
        for sid, a, b in s.execute(
            select(Stitch.id, Stitch.track_a_id, Stitch.track_b_id).where(
                Stitch.sequence_id == state.sequence_id, Stitch.track_a_id.in_({a for a, _ in new}),
                Stitch.track_b_id.in_({b for _, b in new}))
        ).all():
            if (int(a), int(b)) not in state.stitches:
                state.stitches[(int(a), int(b))] = _StitchAcc(int(sid))
    rows = []
    for k, (i, j), a, sh in zip(keys, frag, ta, share, strict=True):
        acc = state.stitches[k]
        acc.links += 1
        acc.share = max(acc.share, float(sh))
        stitched.add(k)
        rows.append({"sequence_id": state.sequence_id, "track_id": int(a), "segment_a_id": int(seg_ids[i]),
                     "segment_b_id": int(state.prev_seg_ids[j]), "score": float(sh), "kind": "fragment",
                     "stitch_id": acc.db_id})
    s.execute(insert(PairConstraint), rows)
    state.fragments += len(rows)


def _finite(value: Any) -> float | None:
    if value is None:
        return None
    v = float(value)
    return v if math.isfinite(v) else None


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
