"""Merge: join one track into another (one object in two tracks).

The joined track keeps the review state both shared, else it is pending without a class; its
kept range covers both. The other track becomes `merged`. The frames that hold the other track
get new artifact files with its points renumbered (the slow step, `plan_merge`, no lock held);
`apply_merge` locks both tracks in id order, whichever direction the merge goes, and writes the
rows in one short transaction (app/services/repair_common.py).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from sqlalchemy import delete, select, update
from sqlalchemy.orm import Session

from app import crud
from app.core.errors import Conflict, NotApplicable
from app.models import Frame, PairConstraint, Segment, Track
from app.services.repair_common import (
    Guard,
    RepairContext,
    add_event,
    link_rows,
    lock_frames,
    lock_tracks,
    read_track,
    rebuild_links,
    refresh_labels,
    remove_files,
    restat,
    track_fields,
    update_by_id,
    write_revision,
)


@dataclass
class MergePlan:
    track_id: int
    version: int
    other_id: int
    other_version: int
    # per frame holding the other track: frame_id, artifact_before, artifact_after, n_segments, n_samples
    frames: list[dict[str, Any]] = field(default_factory=list)


def _check_pair(a: Track, b: Track) -> None:
    if a.sequence_id != b.sequence_id:
        raise NotApplicable(f"tracks {a.id} and {b.id} belong to different sequences")
    for t in (a, b):
        if t.status == "merged":
            raise Conflict(f"track {t.id} was merged into another track already")


def plan_merge(
    session: Session, ctx: RepairContext, track_id: int, guard: Guard, version: int, other_id: int, other_version: int,
) -> MergePlan:
    """Check the merge and write the renumbered artifact files; nothing is locked."""
    if other_id == track_id:
        raise NotApplicable("a track cannot be merged with itself")
    a, b = read_track(session, track_id, version), read_track(session, other_id, other_version)
    for t in sorted((a, b), key=lambda t: t.id):
        guard.check(session, t, renew=False)  # fail early; the write step checks again under the locks
    _check_pair(a, b)
    plan = MergePlan(track_id, version, other_id, other_version)
    frame_ids = session.scalars(select(Segment.frame_id).where(Segment.track_id == b.id).distinct()).all()
    try:
        for frame in session.scalars(select(Frame).where(Frame.id.in_(frame_ids)).order_by(Frame.index)).all():
            art = ctx.artifacts.read_frame(frame.artifact)
            track = np.where(art.track == b.id, a.id, art.track).astype(np.int64)
            plan.frames.append({"frame_id": frame.id, "artifact_before": frame.artifact, "n_segments": frame.n_segments,
                                "n_samples": frame.n_samples,
                                "artifact_after": write_revision(ctx, frame, replace(art, track=track))})
    except BaseException:
        remove_files(ctx, [f["artifact_after"] for f in plan.frames])
        raise
    return plan


def _join(session: Session, a: Track, b: Track, plan: MergePlan) -> list[int]:
    """Move b's segments and frames to a; a's ranges and state; b merged away. The moved ids."""
    moved = [int(i) for i in session.scalars(select(Segment.id).where(Segment.track_id == b.id).order_by(Segment.id)).all()]
    frames = Frame.__table__
    update_by_id(session, frames, [{"id": f["frame_id"], "artifact": f["artifact_after"]} for f in plan.frames])
    segments = Segment.__table__
    session.execute(update(segments).where(segments.c.track_id == b.id).values(track_id=a.id))
    if (a.status, a.label) != (b.status, b.label):
        a.status, a.label, a.label_source = "pending", None, None
    a.first_frame, a.last_frame = min(a.first_frame, b.first_frame), max(a.last_frame, b.last_frame)
    a.keep_start, a.keep_end = min(a.keep_start, b.keep_start), max(a.keep_end, b.keep_end)
    b.status, b.length, b.n_samples, b.n_points = "merged", 0, 0, 0
    b.lease_user_id = b.lease_expires_at = None
    session.flush()
    restat(session, a, ranges_from_segments=False)
    rebuild_links(session, a)
    session.execute(delete(PairConstraint).where(PairConstraint.track_id == b.id, PairConstraint.kind == "must_link"))
    return moved


def _write_merge(session: Session, a: Track, b: Track, plan: MergePlan, guard: Guard) -> None:
    state_a, state_b = crud.review_state(a), crud.review_state(b)
    fields = {a.id: track_fields(a), b.id: track_fields(b)}
    links_before = link_rows(session, [a.id, b.id])
    moved = _join(session, a, b, plan)
    detail = {"other_track": b.id, "frames": plan.frames, "moved_segments": moved, "tracks_before": fields,
              "links_before": links_before, "range_before": [fields[a.id]["first_frame"], fields[a.id]["last_frame"]]}
    ev_a = add_event(session, a, guard.user, "merge", plan.version, state_a, detail)
    ev_b = add_event(session, b, guard.user, "merge", plan.other_version, state_b,
                     {"into_track": a.id, "partner_event": ev_a.id,
                      "range_before": [fields[b.id]["first_frame"], fields[b.id]["last_frame"]]})
    ev_a.detail = {**detail, "partner_event": ev_b.id}
    refresh_labels(session, guard.user, a, b)


def apply_merge(session: Session, plan: MergePlan, guard: Guard, ctx: RepairContext) -> Track:
    """Lock both tracks (id order) and the frames, check, write; commits. The plan's files are
    removed when it does not commit."""
    try:
        tracks = lock_tracks(session, {plan.track_id: plan.version, plan.other_id: plan.other_version}, guard)
        a, b = tracks[plan.track_id], tracks[plan.other_id]
        _check_pair(a, b)
        lock_frames(session, {f["frame_id"]: f["artifact_before"] for f in plan.frames})
        _write_merge(session, a, b, plan, guard)
        session.commit()
    except BaseException:
        session.rollback()
        remove_files(ctx, [f["artifact_after"] for f in plan.frames])
        raise
    return a
