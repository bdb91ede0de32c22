"""Track repair: split a track by a region of its points, merge two tracks, and undo either.

A split moves the track's points inside a region (world frame; every kept frame or one frame)
to a new pending track. Per frame, a segment whose points are all selected moves whole; a cut
segment keeps its row for the points that stay and gets a new row (a new local id) for the
points that go, and both parts' statistics and samples are computed again by the pipeline
(`pipeline.resample`, reached through the ingest backend). A merge moves every segment of one
track into the other. Both rewrite the frames' artifact files under new names
(`ArtifactStore.frame_relpath(..., revision)`) and record in the event's `detail` what they
changed: the artifact file of each frame before and after, the segment rows before, the
constraint rows before and the tracks' fields before. Undo puts all of it back (the old
artifact files were never touched), so the original rows and files come back exactly.

Rules: each track's `version` must be current (stale -> Conflict), its sequence ready; a region
that selects no point, or every point in the kept range -> Invalid; a merged track takes no
action but undo.
"""

from __future__ import annotations

import secrets
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from sqlalchemy import delete, func, insert, select
from sqlalchemy.orm import Session

from app import crud
from app.artifacts import ArtifactStore, FrameArtifact
from app.core.errors import Conflict, Invalid, NotApplicable, NotFound
from app.crud import AuthUser
from app.models import (
    AnchorProposal,
    AnnotationEvent,
    Frame,
    Label,
    PairConstraint,
    Segment,
    Sequence,
    Stitch,
    Track,
    utcnow,
)

GEOMETRY_ACTIONS = ("split", "merge")
SEGMENT_FIELDS = ("track_id", "n_points", "cx", "cy", "cz", "wx", "wy", "wz", "range", "valid", "link_score", "sample_index")
TRACK_FIELDS = (
    "status", "label", "first_frame", "last_frame", "keep_start", "keep_end", "length", "n_samples", "n_points", "mean_range",
    "priority", "label_source",
)


@dataclass(frozen=True)
class RepairContext:
    """What a split needs besides the database: the artifact files, the backend that renders
    samples (`app.jobs.ingest.IngestBackend`) and the sequence's pipeline config."""

    artifacts: ArtifactStore
    backend: Any
    config: Any
    sensor: dict[str, Any] | None


@dataclass(frozen=True)
class Selector:
    """Which points of a frame go: `region` (a `pipeline.regions` region, world frame) or
    `min_height` (metres above the ground estimated again from the frame's points). `record` is
    the request that described it (JSON), kept in the event so that the split can be replayed."""

    region: Any = None
    min_height: float | None = None
    record: dict[str, Any] | None = None
    segments: dict[int, set[int]] | None = None  # frame id -> local ids of whole segments that go


@dataclass(frozen=True)
class SplitResult:
    track: Track
    new_track: Track
    moved_points: int


# ----------------------------------------------------------------------------- shared steps


def _lock_track(session: Session, track_id: int, version: int) -> Track:
    """The track row, locked, of a ready sequence, at `version`, not merged away."""
    track = session.get(Track, track_id, with_for_update=True)
    if track is None:
        raise NotFound(f"track {track_id} not found")
    crud.require_ready(session, track.sequence_id, "tracks can be changed once it is ready")
    if track.version != version:
        raise Conflict(f"stale version {version}: track {track_id} is at version {track.version}")
    return track


def _track_fields(track: Track) -> dict[str, Any]:
    return {f: getattr(track, f) for f in TRACK_FIELDS}


def _segment_row(seg: Segment) -> dict[str, Any]:
    return {"id": seg.id, **{f: getattr(seg, f) for f in SEGMENT_FIELDS}}


def _link_rows(session: Session, track_ids: list[int]) -> list[dict[str, Any]]:
    """The tracks' own must-link constraint rows (what a split or merge rebuilds)."""
    rows = session.execute(
        select(PairConstraint.id, PairConstraint.sequence_id, PairConstraint.track_id, PairConstraint.segment_a_id,
               PairConstraint.segment_b_id, PairConstraint.score)
        .where(PairConstraint.track_id.in_(track_ids), PairConstraint.kind == "must_link")
        .order_by(PairConstraint.id)
    ).mappings().all()
    return [dict(r) for r in rows]


def _rebuild_links(session: Session, track: Track) -> None:
    """The track's must-link pairs as ingest makes them: each valid segment with a sample to the
    previous one, in frame order, scored by the later segment's link score."""
    session.execute(delete(PairConstraint).where(PairConstraint.track_id == track.id, PairConstraint.kind == "must_link"))
    segs = session.execute(
        select(Segment.id, Segment.link_score)
        .where(Segment.track_id == track.id, Segment.valid.is_(True), Segment.sample_index.is_not(None))
        .order_by(Segment.frame_index, Segment.id)
    ).all()
    rows = [
        {"sequence_id": track.sequence_id, "track_id": track.id, "segment_a_id": a.id, "segment_b_id": b.id,
         "score": float(b.link_score or 0.0), "kind": "must_link"}
        for a, b in zip(segs, segs[1:], strict=False)
    ]
    if rows:
        session.execute(insert(PairConstraint), rows)


def _restat(session: Session, track: Track, ranges_from_segments: bool) -> None:
    """Length (frames), samples and range in the kept range, points overall, from the segment rows;
    with `ranges_from_segments` the frame range and kept range become the segments' own."""
    if ranges_from_segments:
        lo, hi = session.execute(
            select(func.min(Segment.frame_index), func.max(Segment.frame_index)).where(Segment.track_id == track.id)
        ).one()
        track.first_frame = track.keep_start = int(lo)
        track.last_frame = track.keep_end = int(hi)
    kept = [Segment.track_id == track.id, Segment.frame_index.between(track.keep_start, track.keep_end)]
    length, n_samples, mean_range = session.execute(
        select(func.count(func.distinct(Segment.frame_index)), func.count(Segment.sample_index), func.avg(Segment.range))
        .where(*kept)
    ).one()
    track.length, track.n_samples, track.mean_range = int(length), int(n_samples), float(mean_range or 0.0)
    track.n_points = int(session.scalar(select(func.coalesce(func.sum(Segment.n_points), 0)).where(Segment.track_id == track.id)))
    track.priority = crud.queue_priority(track.n_points, track.predicted_confidence)


def _event(
    session: Session, track: Track, user: AuthUser, action: str, version: int, before: dict[str, Any],
    detail: dict[str, Any] | None, reverts_event_id: int | None = None,
) -> AnnotationEvent:
    ev = AnnotationEvent(
        track_id=track.id, user_id=user.id, action=action, created_at=utcnow(), version_before=version,
        version_after=version + 1, before=before, after=crud.review_state(track), detail=detail,
        reverts_event_id=reverts_event_id,
    )
    track.version = version + 1
    track.updated_at = ev.created_at
    track.reviewed_by_id = user.id
    session.add(ev)
    session.flush()
    return ev


def _pose(frame: Frame) -> np.ndarray:
    return np.eye(4) if frame.pose is None else np.asarray(frame.pose, np.float64).reshape(4, 4)


def _write_revision(ctx: RepairContext, frame: Frame, art: FrameArtifact) -> str:
    return ctx.artifacts.write_frame(frame.sequence_id, frame.index, art, revision=secrets.token_hex(6))


def _restore_links(session: Session, track_ids: list[int], rows: list[dict[str, Any]]) -> None:
    """The tracks' must-link rows exactly as recorded (same ids)."""
    session.execute(delete(PairConstraint).where(PairConstraint.track_id.in_(track_ids), PairConstraint.kind == "must_link"))
    if rows:
        session.execute(insert(PairConstraint), [{**r, "kind": "must_link"} for r in rows])


def _restore_frames(session: Session, frames: list[dict[str, Any]]) -> None:
    for f in frames:
        frame = session.get(Frame, f["frame_id"])
        assert frame is not None
        frame.artifact, frame.n_segments, frame.n_samples = f["artifact_before"], f["n_segments"], f["n_samples"]


def _refresh_labels(session: Session, user: AuthUser, *tracks: Track) -> None:
    from pipeline.classes import SAMPLE_CLASSES

    session.flush()
    for t in tracks:
        crud.refresh_labels(session, t, user.id, SAMPLE_CLASSES)


# ----------------------------------------------------------------------------- split


@dataclass
class _FrameCut:
    """One frame's part of a split, collected for the event's detail."""

    frame_id: int
    artifact_before: str
    artifact_after: str
    n_segments: int
    n_samples: int


def _selected_points(ctx: RepairContext, frame: Frame, art: FrameArtifact, track_id: int, selector: Selector) -> np.ndarray:
    """(N,) bool: the frame's points of the track that the selector picks."""
    from pipeline.regions import select_points

    mine = art.track == track_id
    out = np.zeros(len(art.points), bool)
    if not mine.any():
        return out
    if selector.segments is not None:
        return mine & np.isin(art.segment, sorted(selector.segments.get(frame.id, ())))
    if selector.min_height is not None:
        height = ctx.backend.height(ctx.sensor, ctx.config, art.points, art.intensity)
        return mine & (height >= selector.min_height)
    pose = _pose(frame)
    world = art.points[mine].astype(np.float64) @ pose[:3, :3].T + pose[:3, 3]
    out[mine] = select_points(selector.region, world)
    return out


def _rerendered(ctx: RepairContext, art: FrameArtifact, segment: np.ndarray, ids: np.ndarray) -> tuple[Any, np.ndarray, np.ndarray]:
    """Statistics of segments `ids` after the cut, and the frame's new (samples, sample_segment):
    the untouched segments' samples as they were, the re-rendered ones appended."""
    res = ctx.backend.resample(ctx.sensor, ctx.config, art.points, art.intensity, segment, ids)
    keep = ~np.isin(art.sample_segment, ids)
    valid_ids = ids[res.sample_of >= 0].astype(np.int32)
    samples = np.concatenate([art.samples[keep], res.samples.astype(np.uint8)]) if len(res.samples) else art.samples[keep]
    return res, samples, np.concatenate([art.sample_segment[keep], valid_ids]).astype(np.int32)


def _set_stats(seg: Segment, res: Any, k: int, pose: np.ndarray, sample_index: int | None) -> None:
    c = res.table.centroid[k].astype(np.float64)
    w = pose[:3, :3] @ c + pose[:3, 3]
    seg.n_points, seg.range, seg.valid = int(res.table.n_points[k]), float(res.table.range[k]), bool(res.table.valid[k])
    seg.cx, seg.cy, seg.cz = (float(v) for v in c)
    seg.wx, seg.wy, seg.wz = (float(v) for v in w)
    seg.sample_index = sample_index


def _split_frame(
    session: Session, ctx: RepairContext, frame: Frame, art: FrameArtifact, selected: np.ndarray, new_track: Track,
    before: dict[int, dict[str, Any]],
) -> tuple[_FrameCut, list[int]]:
    """Move the selected points of one frame to `new_track`; returns the frame's record and the
    ids of the segment rows it created. `before` collects the changed rows' old values."""
    rows = {s.local_id: s for s in session.scalars(select(Segment).where(Segment.frame_id == frame.id)).all()}
    segment, next_local = art.segment.copy(), max(rows) + 1
    cuts: list[tuple[int, int]] = []
    for local in np.unique(art.segment[selected]).tolist():
        row = rows[local]
        before.setdefault(row.id, _segment_row(row))
        part = selected & (art.segment == local)
        if int(part.sum()) == row.n_points:
            row.track_id = new_track.id  # every point goes: the row moves whole
            continue
        segment[part] = next_local
        cuts.append((local, next_local))
        next_local += 1
    track = np.where(selected, new_track.id, art.track).astype(np.int64)
    samples, sample_segment, created = art.samples, art.sample_segment, []
    if cuts:
        ids = np.array([a for a, _ in cuts] + [b for _, b in cuts], np.int32)
        res, samples, sample_segment = _rerendered(ctx, art, segment, ids)
        slot = {int(s): i for i, s in enumerate(sample_segment)}
        for local, row in rows.items():
            if row.sample_index != slot.get(local):
                before.setdefault(row.id, _segment_row(row))
                row.sample_index = slot.get(local)
        pose = _pose(frame)
        for k, local in enumerate(ids.tolist()):
            if local in rows:
                _set_stats(rows[local], res, k, pose, slot.get(local))
                continue
            old = rows[cuts[k - len(cuts)][0]]
            seg = Segment(sequence_id=frame.sequence_id, frame_id=frame.id, frame_index=frame.index, local_id=local,
                          track_id=new_track.id, link_score=old.link_score)
            _set_stats(seg, res, k, pose, slot.get(local))
            session.add(seg)
            session.flush()
            created.append(seg.id)
    cut = _FrameCut(frame.id, frame.artifact, "", frame.n_segments, frame.n_samples)
    new_art = replace(art, segment=segment, track=track, samples=samples, sample_segment=sample_segment)
    cut.artifact_after = frame.artifact = _write_revision(ctx, frame, new_art)
    frame.n_segments, frame.n_samples = next_local, len(samples)
    return cut, created


def _pick_frames(
    session: Session, ctx: RepairContext, track: Track, selector: Selector, frame_index: int | None
) -> list[tuple[Frame, FrameArtifact, np.ndarray]]:
    """The frames in scope with their artifact and selected points (frames with none left out)."""
    lo, hi = track.keep_start, track.keep_end
    if frame_index is not None:
        if not lo <= frame_index <= hi:
            raise NotApplicable(f"frame {frame_index} is outside the kept frames {lo}..{hi} of track {track.id}")
        lo = hi = frame_index
    frame_ids = session.scalars(
        select(Segment.frame_id).where(Segment.track_id == track.id, Segment.frame_index.between(lo, hi)).distinct()
    ).all()
    picks = []
    for frame in session.scalars(select(Frame).where(Frame.id.in_(frame_ids)).order_by(Frame.index)).all():
        art = ctx.artifacts.read_frame(frame.artifact)
        sel = _selected_points(ctx, frame, art, track.id, selector)
        if sel.any():
            picks.append((frame, art, sel))
    return picks


def split_track(
    session: Session, ctx: RepairContext, track_id: int, user: AuthUser, version: int, selector: Selector,
    frame_index: int | None = None,
) -> SplitResult:
    """Move the track's points that `selector` picks (in every kept frame, or in `frame_index`
    only) to a new pending track; record the split event; commit."""
    track = _lock_track(session, track_id, version)
    if track.status == "merged":
        raise Conflict(f"track {track_id} was merged into another track; undo the merge first")
    picks = _pick_frames(session, ctx, track, selector, frame_index)
    moved = int(sum(int(sel.sum()) for _, _, sel in picks))
    if moved == 0:
        raise NotApplicable(f"the region selects no point of track {track_id}")
    kept_points = session.scalar(
        select(func.coalesce(func.sum(Segment.n_points), 0)).where(
            Segment.track_id == track.id, Segment.frame_index.between(track.keep_start, track.keep_end))
    )
    if moved >= int(kept_points or 0):
        raise NotApplicable(f"the region selects every point of track {track_id} in its kept frames; nothing would stay")
    fields_before, links_before = _track_fields(track), _link_rows(session, [track.id])
    key = int(session.scalar(select(func.max(Track.key)).where(Track.sequence_id == track.sequence_id)) or 0) + 1
    f0 = picks[0][0].index
    new = Track(sequence_id=track.sequence_id, key=key, status="pending", first_frame=f0, last_frame=f0, keep_start=f0,
                keep_end=f0, length=0, n_samples=0, n_points=0, mean_range=0.0, version=1, updated_at=utcnow())
    session.add(new)
    session.flush()
    before: dict[int, dict[str, Any]] = {}
    cuts, created = [], []
    for frame, art, sel in picks:
        cut, made = _split_frame(session, ctx, frame, art, sel, new, before)
        cuts.append(cut.__dict__)
        created += made
    session.flush()
    _restat(session, track, ranges_from_segments=False)
    _restat(session, new, ranges_from_segments=True)
    _rebuild_links(session, track)
    _rebuild_links(session, new)
    detail = {
        "new_track": new.id, "frame_index": frame_index, "moved_points": moved, "frames": cuts,
        "segments_before": list(before.values()), "created_segments": created, "track_before": fields_before,
        "links_before": links_before, "range_before": [track.first_frame, track.last_frame],
        "region": selector.record,
    }
    _event(session, track, user, "split", version, crud.review_state(track), detail)
    _refresh_labels(session, user, track, new)
    session.commit()
    return SplitResult(track, new, moved)


def predicted_selector(session: Session, ctx: RepairContext, track_id: int, model_id: int, class_name: str,
                       record: dict[str, Any]) -> Selector:
    """The track's kept segments that model `model_id` classifies as `class_name` (whole
    segments: a split in time, e.g. the frames where a tracked person merged into a wall)."""
    from app.jobs.models_util import get_model_version
    from pipeline.errors import DataError
    from pipeline.model import load_checkpoint, predict

    track = crud.get_track(session, track_id)
    mv = get_model_version(session, model_id)
    try:
        model, meta = load_checkpoint(mv.path, "cpu")
    except DataError as exc:
        raise Invalid(f"model {model_id}: {exc}") from None
    if class_name not in meta.classes:
        raise NotApplicable(f"model {model_id} has no class {class_name!r}; its classes: {', '.join(meta.classes)}")
    rows = session.execute(
        select(Segment.frame_id, Segment.local_id, Segment.sample_index, Frame.artifact)
        .join(Frame, Frame.id == Segment.frame_id)
        .where(Segment.track_id == track_id, Segment.sample_index.is_not(None),
               Segment.frame_index.between(track.keep_start, track.keep_end))
    ).all()
    samples = [ctx.artifacts.read_arrays(r.artifact, ("samples",))["samples"][r.sample_index] for r in rows]
    picked: dict[int, set[int]] = {}
    if samples:
        probs = predict(model, np.stack(samples))
        for r, p in zip(rows, probs, strict=True):
            if meta.classes[int(p.argmax())] == class_name:
                picked.setdefault(int(r.frame_id), set()).add(int(r.local_id))
    return Selector(record=record, segments=picked)


# ----------------------------------------------------------------------------- merge


def _retrack_frames(session: Session, ctx: RepairContext, source_id: int, target_id: int) -> list[dict[str, Any]]:
    """Rewrite the per-point track ids source -> target in every frame holding the source track."""
    frame_ids = session.scalars(select(Segment.frame_id).where(Segment.track_id == source_id).distinct()).all()
    out = []
    for frame in session.scalars(select(Frame).where(Frame.id.in_(frame_ids)).order_by(Frame.index)).all():
        art = ctx.artifacts.read_frame(frame.artifact)
        track = np.where(art.track == source_id, target_id, art.track).astype(np.int64)
        rec = {"frame_id": frame.id, "artifact_before": frame.artifact, "n_segments": frame.n_segments,
               "n_samples": frame.n_samples}
        frame.artifact = rec["artifact_after"] = _write_revision(ctx, frame, replace(art, track=track))
        out.append(rec)
    return out


def merge_tracks(
    session: Session, ctx: RepairContext, track_id: int, user: AuthUser, version: int, other_id: int, other_version: int,
) -> Track:
    """Join track `other_id` into `track_id` (one object in two tracks); each version must be
    current. The joined track keeps the review state both shared, else it is pending without a
    class; its kept range covers both. The other track becomes `merged`. Commits."""
    if other_id == track_id:
        raise NotApplicable("a track cannot be merged with itself")
    locked = {i: _lock_track(session, i, v) for i, v in sorted([(track_id, version), (other_id, other_version)])}
    a, b = locked[track_id], locked[other_id]
    if a.sequence_id != b.sequence_id:
        raise NotApplicable(f"tracks {a.id} and {b.id} belong to different sequences")
    for t in (a, b):
        if t.status == "merged":
            raise Conflict(f"track {t.id} was merged into another track already")
    state_a, state_b = crud.review_state(a), crud.review_state(b)
    fields = {a.id: _track_fields(a), b.id: _track_fields(b)}
    links_before = _link_rows(session, [a.id, b.id])
    moved = list(session.scalars(select(Segment.id).where(Segment.track_id == b.id).order_by(Segment.id)).all())
    frames = _retrack_frames(session, ctx, b.id, a.id)
    session.execute(Segment.__table__.update().where(Segment.__table__.c.track_id == b.id).values(track_id=a.id))
    if (a.status, a.label) != (b.status, b.label):
        a.status, a.label, a.label_source = "pending", None, None
    a.first_frame, a.last_frame = min(a.first_frame, b.first_frame), max(a.last_frame, b.last_frame)
    a.keep_start, a.keep_end = min(a.keep_start, b.keep_start), max(a.keep_end, b.keep_end)
    b.status, b.length, b.n_samples, b.n_points = "merged", 0, 0, 0
    b.lease_user_id = b.lease_expires_at = None
    session.flush()
    _restat(session, a, ranges_from_segments=False)
    _rebuild_links(session, a)
    session.execute(delete(PairConstraint).where(PairConstraint.track_id == b.id, PairConstraint.kind == "must_link"))
    detail = {"other_track": b.id, "frames": frames, "moved_segments": moved, "tracks_before": fields,
              "links_before": links_before, "range_before": [fields[a.id]["first_frame"], fields[a.id]["last_frame"]]}
    ev_a = _event(session, a, user, "merge", version, state_a, detail)
    ev_b = _event(session, b, user, "merge", other_version, state_b,
                  {"into_track": a.id, "partner_event": ev_a.id,
                   "range_before": [fields[b.id]["first_frame"], fields[b.id]["last_frame"]]})
    ev_a.detail = {**detail, "partner_event": ev_b.id}
    _refresh_labels(session, user, a, b)
    session.commit()
    return a


# ----------------------------------------------------------------------------- undo


def undo(
    session: Session, ctx: RepairContext, track_id: int, user: AuthUser, version: int, override_lease: bool = False,
) -> Track:
    """Revert the caller's last not-yet-undone action on the track: a split or merge here, any
    other action through `crud.apply_action`. Nothing to undo -> Conflict. Commits."""
    from pipeline.classes import SAMPLE_CLASSES

    if session.get(Track, track_id) is None:
        raise NotFound(f"track {track_id} not found")
    ev = crud.last_undoable_event(session, track_id, user.id)
    if ev is None or ev.action not in GEOMETRY_ACTIONS:
        return crud.apply_action(session, track_id, user, "undo", version, sample_classes=SAMPLE_CLASSES,
                                 override_lease=override_lease)
    track = _lock_track(session, track_id, version)
    if ev.action == "split":
        return _undo_split(session, track, ev, user, version)
    return _undo_merge(session, track, ev, user, version)


def _restore_track(track: Track, fields: dict[str, Any]) -> None:
    for f, v in fields.items():
        setattr(track, f, v)


def _drop_track(session: Session, track: Track) -> None:
    """Delete a track that a split created, with every row that points at it."""
    for table, col in ((Label, Label.track_id), (PairConstraint, PairConstraint.track_id),
                       (AnchorProposal, AnchorProposal.track_id), (AnnotationEvent, AnnotationEvent.track_id)):
        session.execute(delete(table).where(col == track.id))
    session.execute(delete(Stitch).where((Stitch.track_a_id == track.id) | (Stitch.track_b_id == track.id)))
    session.flush()
    session.delete(track)


def _undo_split(session: Session, track: Track, ev: AnnotationEvent, user: AuthUser, version: int) -> Track:
    d = ev.detail or {}
    new = session.get(Track, d["new_track"], with_for_update=True)
    if new is None or _live_events(session, new.id):
        raise Conflict(f"track {d['new_track']} cut off by this split has changed since; undo its actions first")
    before = crud.review_state(track)
    created = d["created_segments"]
    _restore_frames(session, d["frames"])
    session.execute(delete(Label).where(Label.segment_id.in_(created)))
    session.execute(delete(PairConstraint).where(
        PairConstraint.segment_a_id.in_(created) | PairConstraint.segment_b_id.in_(created)))
    # segments first: a segment the split moved whole belongs to the new track, and dropping that
    # track deletes its segments (ON DELETE CASCADE)
    if d["segments_before"]:
        session.execute(Segment.__table__.update().where(Segment.__table__.c.id == _bind_id()),
                        [{"_id": r["id"], **{f: r[f] for f in SEGMENT_FIELDS}} for r in d["segments_before"]])
    _drop_track(session, new)
    session.execute(delete(Segment).where(Segment.id.in_(created)))
    _restore_track(track, d["track_before"])
    _restore_links(session, [track.id], d["links_before"])
    _event(session, track, user, "undo", version, before, None, reverts_event_id=ev.id)
    _refresh_labels(session, user, track)
    session.commit()
    return track


def _live_events(session: Session, track_id: int) -> int:
    """How many actions on the track no undo has reverted (0: it is as the split made it)."""
    reverted = select(AnnotationEvent.reverts_event_id).where(
        AnnotationEvent.track_id == track_id, AnnotationEvent.reverts_event_id.is_not(None))
    return int(session.scalar(select(func.count()).select_from(AnnotationEvent).where(
        AnnotationEvent.track_id == track_id, AnnotationEvent.action != "undo", AnnotationEvent.id.not_in(reverted))) or 0)


def _bind_id() -> Any:
    from sqlalchemy import bindparam

    return bindparam("_id")


def _undo_merge(session: Session, track: Track, ev: AnnotationEvent, user: AuthUser, version: int) -> Track:
    d = ev.detail or {}
    if "into_track" in d:  # undo asked on the merged-away track: its partner holds the record
        main_ev = session.get(AnnotationEvent, d["partner_event"])
        other_ev = ev
    else:
        main_ev, other_ev = ev, session.get(AnnotationEvent, d["partner_event"])
    assert main_ev is not None and other_ev is not None
    md = main_ev.detail or {}
    a = session.get(Track, main_ev.track_id, with_for_update=True)
    b = session.get(Track, other_ev.track_id, with_for_update=True)
    assert a is not None and b is not None
    for t, e in ((a, main_ev), (b, other_ev)):
        if t.version != e.version_after:
            raise Conflict(f"track {t.id} has changed since the merge; undo its later actions first")
    states = {a.id: crud.review_state(a), b.id: crud.review_state(b)}
    _restore_frames(session, md["frames"])
    if md["moved_segments"]:
        session.execute(Segment.__table__.update().where(Segment.__table__.c.id.in_(md["moved_segments"])).values(track_id=b.id))
    for t in (a, b):
        _restore_track(t, md["tracks_before"][str(t.id)] if str(t.id) in md["tracks_before"] else md["tracks_before"][t.id])
    _restore_links(session, [a.id, b.id], md["links_before"])
    for t, e in ((a, main_ev), (b, other_ev)):
        _event(session, t, user, "undo", t.version, states[t.id], None, reverts_event_id=e.id)
    _refresh_labels(session, user, a, b)
    session.commit()
    return track


def repair_context(session: Session, settings: Any, artifacts: ArtifactStore, sequence_id: int) -> RepairContext:
    """The context of a sequence: its sensor, its pipeline config (settings' file + its overrides)."""
    from app.jobs.ingest import get_backend

    seq = session.get(Sequence, sequence_id)
    if seq is None:
        raise NotFound(f"sequence {sequence_id} not found")
    backend = get_backend()
    return RepairContext(artifacts, backend, backend.config(settings.pipeline_config, seq.config), seq.sensor)

