"""The rows an ingest writes: tracks, frames, segments, constraint pairs and stitches.

`IngestRows` keeps the running statistics of every track and stitch between batches; its
constraint pairs come from `pipeline.links.LinkBuilder`, each member named by its segment row id.
A frame row is written together with all its segments and pairs (one transaction per batch,
`app/jobs/ingest.py`).
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from sqlalchemy import case, insert, select, update
from sqlalchemy.orm import Session

from app.core.errors import Conflict, NotFound
from app.crud.bulk_load import clear_sequence_rows
from app.crud.datasets import sequence_stats
from app.crud.review_queue import queue_priority
from app.models import Frame, Job, PairConstraint, Segment, Sequence, Stitch, Track, utcnow
from pipeline.links import LinkBuilder


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


@dataclass
class _StitchAcc:
    """Running statistics of one stitch during ingest."""

    db_id: int
    links: int = 0
    share: float = 0.0


@dataclass
class IngestRows:
    """What an ingest has written so far, by track key (the pipeline's track id)."""

    sequence_id: int
    tracks: dict[int, _TrackAcc] = field(default_factory=dict)
    stitches: dict[tuple[int, int], _StitchAcc] = field(default_factory=dict)  # (track a, track b) db ids
    links: LinkBuilder = field(default_factory=LinkBuilder)
    frames: int = 0
    segments: int = 0
    constraints: int = 0
    fragments: int = 0
    _touched: set[int] = field(default_factory=set)
    _stitched: set[tuple[int, int]] = field(default_factory=set)

    def db_tracks(self, fr: Any) -> np.ndarray:
        """(S,) int64 database track id of each segment of a frame, 0 = none."""
        keys = np.asarray(fr.segments.track_id, dtype=np.int64)
        db_track = np.zeros(len(keys), np.int64)
        for i in np.flatnonzero(keys > 0):
            db_track[i] = self.tracks[int(keys[i])].db_id
        return db_track

    def insert_new_tracks(self, s: Session, frames: Iterable[Any]) -> None:
        """A pending track row per track key first seen in `frames`."""
        first_seen: dict[int, int] = {}
        for fr in frames:
            for key in np.unique(fr.segments.track_id):
                k = int(key)
                if k > 0 and k not in self.tracks and k not in first_seen:
                    first_seen[k] = fr.index
        if not first_seen:
            return
        now = utcnow()
        s.execute(insert(Track), [
            {"sequence_id": self.sequence_id, "key": k, "status": "pending", "first_frame": f, "last_frame": f,
             "keep_start": f, "keep_end": f, "length": 0, "n_samples": 0, "n_points": 0, "mean_range": 0.0,
             "version": 1, "updated_at": now}
            for k, f in first_seen.items()
        ])
        # plain executemany, then read the ids back (bulk RETURNING in order goes row by row on SQLite)
        keys = list(first_seen)
        for i in range(0, len(keys), 5000):
            for db_id, key in s.execute(select(Track.id, Track.key).where(
                    Track.sequence_id == self.sequence_id, Track.key.in_(keys[i : i + 5000]))).all():
                self.tracks[int(key)] = _TrackAcc(int(db_id), first_seen[int(key)], first_seen[int(key)])

    def write_frame(self, s: Session, fr: Any, rel: str) -> None:
        """The frame's row, its segments' rows, its track pairs and its fragment pairs."""
        n_seg = len(fr.segments.n_points)
        sample_index = np.full(n_seg, -1, np.int64)
        sample_index[np.asarray(fr.sample_segment, dtype=np.int64)] = np.arange(len(fr.sample_segment))
        frame_id = _insert_frame(s, self.sequence_id, fr, rel)
        self.frames += 1
        seg_ids = _insert_segments(s, self.sequence_id, fr, frame_id, self.db_tracks(fr), sample_index) \
            if n_seg else np.zeros(0, np.int64)
        self.segments += n_seg
        self._extend_tracks(fr, sample_index)
        member = np.asarray(fr.segments.valid, bool) & (sample_index >= 0)
        links = self.links.add(fr.segments.track_id, member, seg_ids, getattr(fr, "fragments", None),
                               getattr(fr, "fragment_share", None))
        if len(links.pairs):
            scores = [_finite(fr.segments.link_score[k]) for k in links.later.tolist()]
            s.execute(insert(PairConstraint), [
                {"sequence_id": self.sequence_id, "track_id": self.tracks[key].db_id, "segment_a_id": a,
                 "segment_b_id": b, "score": 0.0 if sc is None else sc, "kind": "must_link"}
                for key, (a, b), sc in zip(links.track.tolist(), links.pairs.tolist(), scores, strict=True)
            ])
            self.constraints += len(links.pairs)
        if len(links.fragments):
            self._write_fragments(s, links, np.asarray(fr.segments.track_id, np.int64)[links.fragments[:, 0]])

    def gap(self) -> None:
        """A frame that is not stored: no fragment pair reaches across it."""
        self.links.gap()

    def _extend_tracks(self, fr: Any, sample_index: np.ndarray) -> None:
        seg = fr.segments
        keys = np.asarray(seg.track_id, dtype=np.int64)
        for i in np.flatnonzero(keys > 0):
            acc = self.tracks[int(keys[i])]
            acc.n_samples += int(bool(seg.valid[i]) and sample_index[i] >= 0)
            acc.last = int(fr.index)
            acc.length += 1
            acc.n_points += int(seg.n_points[i])
            acc.range_sum += float(seg.range[i])
            self._touched.add(int(keys[i]))

    def _write_fragments(self, s: Session, links: Any, this_key: np.ndarray) -> None:
        """A stitch row per new pair of tracks, a `fragment` constraint row per fragment pair."""
        key_db = {k: acc.db_id for k, acc in self.tracks.items()}
        stitch = [(key_db[a], key_db[b]) for a, b in links.stitch.tolist()]
        keys = [(min(a, b), max(a, b)) for a, b in stitch]
        new = sorted({k for k in keys if k not in self.stitches})
        if new:
            s.execute(insert(Stitch), [{"sequence_id": self.sequence_id, "track_a_id": a, "track_b_id": b,
                                        "links": 0, "share": 0.0, "status": "pending", "version": 1} for a, b in new])
            for sid, a, b in s.execute(
                select(Stitch.id, Stitch.track_a_id, Stitch.track_b_id).where(
                    Stitch.sequence_id == self.sequence_id, Stitch.track_a_id.in_({a for a, _ in new}),
                    Stitch.track_b_id.in_({b for _, b in new}))
            ).all():
                self.stitches.setdefault((int(a), int(b)), _StitchAcc(int(sid)))
        this_track = [key_db[k] for k in this_key.tolist()]
        rows = []
        for k, (a, b), t, sh in zip(keys, links.fragment_refs.tolist(), this_track, links.share.tolist(), strict=True):
            acc = self.stitches[k]
            acc.links += 1
            acc.share = max(acc.share, float(sh))
            self._stitched.add(k)
            rows.append({"sequence_id": self.sequence_id, "track_id": t, "segment_a_id": a, "segment_b_id": b,
                         "score": float(sh), "kind": "fragment", "stitch_id": acc.db_id})
        s.execute(insert(PairConstraint), rows)
        self.fragments += len(rows)

    def update_statistics(self, s: Session) -> None:
        """The statistics of the tracks and stitches this batch changed."""
        if self._stitched:
            s.execute(update(Stitch), [{"id": self.stitches[k].db_id, "links": self.stitches[k].links,
                                        "share": self.stitches[k].share} for k in sorted(self._stitched)])
        if self._touched:
            s.execute(update(Track), [
                {"id": t.db_id, "last_frame": t.last, "keep_end": t.last, "length": t.length,
                 "n_samples": t.n_samples, "n_points": t.n_points, "priority": queue_priority(t.n_points, None),
                 "mean_range": t.range_sum / max(t.length, 1)}
                for t in (self.tracks[k] for k in sorted(self._touched))
            ])
        self._touched, self._stitched = set(), set()

    def mark_ready(self, s: Session) -> None:
        """The sequence `ready`; the split's key counter starts above every ingested key."""
        top = max(self.tracks, default=0)
        s.execute(update(Sequence).where(Sequence.id == self.sequence_id).values(
            status="ready", n_frames=self.frames,
            last_track_key=case((Sequence.last_track_key >= top, Sequence.last_track_key), else_=top)))


def _insert_frame(s: Session, sequence_id: int, fr: Any, rel: str) -> int:
    """Insert the frame's row; its id."""
    pose = getattr(fr, "T_world_lidar", None)
    return s.execute(insert(Frame).returning(Frame.id), [{
        "sequence_id": sequence_id, "index": int(fr.index), "name": str(fr.name), "n_points": len(fr.segment),
        "n_segments": len(fr.segments.n_points), "n_samples": len(fr.sample_segment), "artifact": rel,
        "timestamp": _finite(getattr(fr, "time", None)),
        "pose": None if pose is None else [float(v) for v in np.asarray(pose).reshape(-1)],
    }]).scalar_one()


def _insert_segments(
    s: Session, sequence_id: int, fr: Any, frame_id: int, db_track: np.ndarray, sample_index: np.ndarray
) -> np.ndarray:
    """Insert a row per segment of the frame; (S,) int64 their ids by local segment id."""
    seg = fr.segments
    n_seg = len(seg.n_points)
    cen, cw = np.asarray(seg.centroid, np.float64), np.asarray(seg.centroid_world, np.float64)
    s.execute(insert(Segment), [
        {"sequence_id": sequence_id, "frame_id": frame_id, "frame_index": int(fr.index), "local_id": i,
         "track_id": int(db_track[i]) or None, "n_points": int(seg.n_points[i]), "cx": float(cen[i, 0]),
         "cy": float(cen[i, 1]), "cz": float(cen[i, 2]), "wx": float(cw[i, 0]), "wy": float(cw[i, 1]),
         "wz": float(cw[i, 2]), "range": float(seg.range[i]), "valid": bool(seg.valid[i]),
         "link_score": _finite(seg.link_score[i]),
         "sample_index": int(sample_index[i]) if sample_index[i] >= 0 else None}
        for i in range(n_seg)
    ])
    seg_ids = np.zeros(n_seg, np.int64)
    for seg_id, local_id in s.execute(select(Segment.id, Segment.local_id).where(Segment.frame_id == frame_id)).all():
        seg_ids[local_id] = seg_id
    return seg_ids


def _finite(value: Any) -> float | None:
    if value is None:
        return None
    v = float(value)
    return v if math.isfinite(v) else None


def begin_ingest(s: Session, sequence_id: int, job_id: int, force: bool) -> tuple[str, str, Any] | dict[str, Any]:
    """Roll back what an earlier attempt wrote and mark the sequence `ingesting` by `job_id`:
    its (path, format, config overrides); or, when this job already finished it before a crash,
    the ingest's result. NotFound / Conflict (ready, not `force`)."""
    seq = s.get(Sequence, sequence_id)
    if seq is None:
        raise NotFound(f"sequence {sequence_id} not found")
    if seq.status == "ready" and seq.ingest_job_id == job_id:
        return {"sequence_id": seq.id, **sequence_stats(s, seq)}
    if seq.status == "ready" and not force:
        raise Conflict(f"sequence {seq.id} is already ingested; pass force=true to redo it")
    clear_sequence_rows(s, seq.id)
    seq.status, seq.n_frames, seq.ingest_job_id = "ingesting", 0, job_id
    return seq.path, seq.format, seq.config


def record_source(s: Session, sequence_id: int, fmt: str, sensor: dict[str, Any]) -> None:
    """The format and sensor model ingest found (a repair re-renders samples with that sensor)."""
    s.execute(update(Sequence).where(Sequence.id == sequence_id).values(format=fmt, sensor=sensor))


def mark_failed(s: Session, sequence_id: int) -> None:
    s.execute(update(Sequence).where(Sequence.id == sequence_id).values(status="failed"))


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
    `begin_ingest` reads "ready with my job id" as "I finished before a crash" and returns at once,
    so pointing a ready sequence at a queued job would turn `force` into a no-op."""
    seq = s.get(Sequence, sequence_id)
    if seq is not None and seq.status != "ready":
        seq.ingest_job_id = job_id


def check_can_ingest(s: Session, sequence_id: int, force: bool) -> None:
    """The sequence exists, is not being ingested already, and is not ready unless `force`."""
    seq = s.get(Sequence, sequence_id)
    if seq is None:
        raise NotFound(f"sequence {sequence_id} not found")
    active = active_ingest_job(s, sequence_id)
    if active is not None:
        raise Conflict(f"sequence {sequence_id} already has ingest job {active}")
    if seq.status == "ready" and not force:
        raise Conflict(f"sequence {sequence_id} is already ingested; pass force=true to redo it")
