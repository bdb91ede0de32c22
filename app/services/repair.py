"""Track repair: split a track by a region of its points, merge two tracks, and undo either.

A split moves the track's points inside a region (world frame; every kept frame or one frame)
to a new pending track (app/services/repair_split.py); a merge moves every segment of one track into
the other (app/services/repair_merge.py). Both rewrite the frames' artifact files under new names
(`ArtifactStore.frame_relpath(..., revision)`) and record in the event's `detail` what they
changed: the artifact file of each frame before and after, the segment rows before, the
constraint rows before and the tracks' fields before. Undo puts all of it back (the old
artifact files were never touched), so the original rows and files come back exactly; the track
a split created is deleted, and its id and key are never given again (app/crud/track_ids.py).

Each runs its slow part with no lock held, then writes in one short transaction that locks
tracks in id order, then frames in id order (app/services/repair_common.py).

Rules: each track's `version` must be current (stale -> Conflict), its sequence ready; a region
that selects no point, or every point in the kept range -> NotApplicable; a merged track takes
no action but undo.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from sqlalchemy import delete, func, select
from sqlalchemy.orm import Session

from app import crud
from app.artifacts import ArtifactStore
from app.core.errors import Conflict, Invalid, NotApplicable, NotFound, StaleVersion
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
)
from app.services.repair_common import (
    SEGMENT_FIELDS,
    Guard,
    RepairContext,
    add_event,
    lock_tracks,
    refresh_labels,
    restore_frames,
    restore_links,
    update_segments,
)
from app.services.repair_merge import MergePlan, apply_merge, plan_merge
from app.services.repair_split import Selector, SplitPlan, SplitResult, apply_split, plan_split

GEOMETRY_ACTIONS = ("split", "merge")

__all__ = [
    "GEOMETRY_ACTIONS", "RepairContext", "Selector", "SplitPlan", "SplitResult", "MergePlan", "plan_split",
    "apply_split", "plan_merge", "apply_merge", "undo", "predicted_selector", "repair_context",
]


def predicted_selector(session: Session, ctx: RepairContext, track_id: int, model_id: int, class_name: str,
                       record: dict[str, Any]) -> Selector:
    """The track's kept segments that model `model_id` classifies as `class_name` (whole
    segments: a split in time, e.g. the frames where a tracked person merged into a wall)."""
    from app.crud.model_versions import get_model_version
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


# ----------------------------------------------------------------------------- undo


def undo(session: Session, track_id: int, guard: Guard, version: int, override_lease: bool = False) -> Track:
    """Revert the caller's last not-yet-undone action on the track: a split or merge here, any
    other action through `crud.apply_action`. Nothing to undo -> Conflict. Commits. (No file is
    written: undo points the frames back at the files they had.)"""
    if session.get(Track, track_id) is None:
        raise NotFound(f"track {track_id} not found")
    ev = crud.last_undoable_event(session, track_id, guard.user.id)
    if ev is None or ev.action not in GEOMETRY_ACTIONS:
        return crud.apply_action(session, track_id, guard.user, "undo", version,
                                 override_lease=override_lease, lease_seconds=getattr(guard, "lease_seconds", None))
    if ev.action == "split":
        return _undo_split(session, track_id, ev, guard, version)
    return _undo_merge(session, track_id, ev, guard, version)


def _restore_track(track: Track, fields: dict[str, Any]) -> None:
    for f, v in fields.items():
        setattr(track, f, v)


def _lock_frames_after(session: Session, frames: list[dict[str, Any]]) -> None:
    """Lock the frames an undo points back; Conflict when a later repair rewrote one since."""
    expected = {int(f["frame_id"]): f["artifact_after"] for f in frames}
    rows = session.execute(
        select(Frame.id, Frame.artifact).where(Frame.id.in_(sorted(expected))).order_by(Frame.id)
        .with_for_update(key_share=True)
    ).all()
    for r in rows:
        if r.artifact != expected[int(r.id)]:
            raise Conflict(f"frame {r.id} was changed by a later split or merge of another track; undo that first")


def _drop_track(session: Session, track: Track) -> None:
    """Delete a track that a split created, with every row that points at it."""
    for table, col in ((Label, Label.track_id), (PairConstraint, PairConstraint.track_id),
                       (AnchorProposal, AnchorProposal.track_id), (AnnotationEvent, AnnotationEvent.track_id)):
        session.execute(delete(table).where(col == track.id))
    session.execute(delete(Stitch).where((Stitch.track_a_id == track.id) | (Stitch.track_b_id == track.id)))
    session.flush()
    session.delete(track)


def _live_events(session: Session, track_id: int) -> int:
    """How many actions on the track no undo has reverted (0: it is as the split made it)."""
    reverted = select(AnnotationEvent.reverts_event_id).where(
        AnnotationEvent.track_id == track_id, AnnotationEvent.reverts_event_id.is_not(None))
    return int(session.scalar(select(func.count()).select_from(AnnotationEvent).where(
        AnnotationEvent.track_id == track_id, AnnotationEvent.action != "undo", AnnotationEvent.id.not_in(reverted))) or 0)


def _undo_split(session: Session, track_id: int, ev: AnnotationEvent, guard: Guard, version: int) -> Track:
    d = ev.detail or {}
    new_id = int(d["new_track"])
    tracks = lock_tracks(session, {track_id: version}, guard)
    track, new = tracks[track_id], session.get(Track, new_id, with_for_update={"key_share": True}, populate_existing=True)
    if new is None or _live_events(session, new.id):
        raise Conflict(f"track {new_id} cut off by this split has changed since; undo its actions first")
    guard.check(session, new)  # the new track goes away: nobody else may hold it
    _lock_frames_after(session, d["frames"])
    before = crud.review_state(track)
    created = d["created_segments"]
    restore_frames(session, d["frames"])
    session.execute(delete(Label).where(Label.segment_id.in_(created)))
    session.execute(delete(PairConstraint).where(
        PairConstraint.segment_a_id.in_(created) | PairConstraint.segment_b_id.in_(created)))
    # segments first: a segment the split moved whole belongs to the new track, and dropping that
    # track deletes its segments (ON DELETE CASCADE)
    update_segments(session, [{"id": r["id"], **{f: r[f] for f in SEGMENT_FIELDS}} for r in d["segments_before"]])
    _drop_track(session, new)
    session.execute(delete(Segment).where(Segment.id.in_(created)))
    _restore_track(track, d["track_before"])
    restore_links(session, [track.id], d["links_before"])
    add_event(session, track, guard.user, "undo", version, before, None, reverts_event_id=ev.id)
    refresh_labels(session, guard.user, track)
    session.commit()
    return track


def _merge_events(session: Session, ev: AnnotationEvent) -> tuple[AnnotationEvent, AnnotationEvent]:
    """(the joined track's merge event, the merged-away track's), from either of them."""
    d = ev.detail or {}
    partner = session.get(AnnotationEvent, d["partner_event"])
    assert partner is not None
    return (partner, ev) if "into_track" in d else (ev, partner)


def _undo_merge(session: Session, track_id: int, ev: AnnotationEvent, guard: Guard, version: int) -> Track:
    main_ev, other_ev = _merge_events(session, ev)
    md = main_ev.detail or {}
    expected = {main_ev.track_id: main_ev.version_after, other_ev.track_id: other_ev.version_after}
    if expected.get(track_id) != version:
        raise StaleVersion(f"stale version {version}: track {track_id} has changed since the merge")
    try:
        tracks = lock_tracks(session, expected, guard)
    except StaleVersion as exc:
        raise StaleVersion(f"{exc.detail}; it has changed since the merge: undo its later actions first") from None
    a, b = tracks[main_ev.track_id], tracks[other_ev.track_id]
    _lock_frames_after(session, md["frames"])
    states = {a.id: crud.review_state(a), b.id: crud.review_state(b)}
    restore_frames(session, md["frames"])
    if md["moved_segments"]:
        session.execute(Segment.__table__.update().where(Segment.__table__.c.id.in_(md["moved_segments"])).values(track_id=b.id))
    for t in (a, b):
        _restore_track(t, md["tracks_before"][str(t.id)] if str(t.id) in md["tracks_before"] else md["tracks_before"][t.id])
    restore_links(session, [a.id, b.id], md["links_before"])
    for t, e in ((a, main_ev), (b, other_ev)):
        add_event(session, t, guard.user, "undo", t.version, states[t.id], None, reverts_event_id=e.id)
    refresh_labels(session, guard.user, a, b)
    session.commit()
    return tracks[track_id]


def repair_context(session: Session, settings: Any, artifacts: ArtifactStore, sequence_id: int) -> RepairContext:
    """The context of a sequence: its sensor, its pipeline config (settings' file + its overrides)."""
    seq = session.get(Sequence, sequence_id)
    if seq is None:
        raise NotFound(f"sequence {sequence_id} not found")
    return RepairContext(artifacts, crud.pipeline_config(settings.pipeline_config, seq.config), seq.sensor)
