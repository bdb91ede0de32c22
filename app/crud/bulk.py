"""Bulk accept: every pending track the model predicts as one class with at least a confidence,
accepted with that class in one operator action, and undone in one.

The operation is one `BulkAction` row. Each track it labels also gets a `bulk_accept` event (its
review state before and after, the row's id in the detail) and label rows with source `bulk`, so
a single track of a bulk is undone, replayed and audited like any other action, and exports and
statistics tell bulk labels from reviewed ones. Tracks another operator has leased are left out:
they are under review.

A bulk takes only tracks at least as large as the smallest reviewed track its held-out precision
was measured on (`held_out_precision`): the reviews the model is checked on are the queue's
largest tracks, and below their sizes the check says nothing. Measured on kitti_seq02
(docs/effort.md), the small tracks a bulk took without this floor were wrong far more often than
the check said (pieces of ground called bush).
"""

from __future__ import annotations

from typing import Any

from sqlalchemy import func, insert, or_, select
from sqlalchemy.orm import Session

from app.core.errors import Conflict, NotFound
from app.crud.datasets import require_ready
from app.crud.ground_regions import region_operations
from app.crud.label_sets import check_class, existing_label_set, sequence_label_set
from app.crud.review import REVIEW_FIELDS, refresh_labels, review_state, stored_state
from app.crud.users import AuthUser
from app.models import AnnotationEvent, BulkAction, Job, Track, utcnow
from pipeline.label_sets import LabelSet

PREVIEW_TRACKS = 20  # the largest candidates a preview lists for the operator to look at


def _candidates(sequence_id: int, class_name: str, min_confidence: float, user: AuthUser,
                min_points: int | None) -> Any:
    """SQL: the pending tracks of the sequence predicted as `class_name` with a confidence of at
    least `min_confidence` and at least `min_points` points (None: any) that nobody else holds a
    lease on, largest first."""
    now = utcnow()
    return (
        select(Track)
        .where(
            Track.sequence_id == sequence_id,
            Track.status == "pending",
            Track.predicted_class == class_name,
            Track.predicted_confidence >= min_confidence,
            Track.n_points >= (min_points or 0),
            or_(Track.lease_user_id.is_(None), Track.lease_user_id == user.id, Track.lease_expires_at < now),
        )
        .order_by(Track.n_points.desc(), Track.id)
    )


def _label_set(session: Session, sequence_id: int, class_name: str) -> LabelSet:
    """The sequence's label set once `class_name` is one of its classes (Invalid otherwise)."""
    label_set = sequence_label_set(session, sequence_id)
    if label_set is None:
        raise NotFound(f"sequence {sequence_id} not found")
    check_class("class_name", class_name, label_set)
    return label_set


def bulk_preview(session: Session, sequence_id: int, class_name: str, min_confidence: float,
                 user: AuthUser) -> dict[str, Any]:
    """What a bulk accept would label now: the number of tracks and points, their confidences
    (min, mean) and the largest tracks' ids, for the operator to look at before accepting, and the
    held-out check with the size floor it sets (module docstring)."""
    _label_set(session, sequence_id, class_name)
    require_ready(session, sequence_id, "its tracks can be accepted once it is ready")
    precision, support, floor = held_out_precision(session, sequence_id, class_name, min_confidence)
    sub = _candidates(sequence_id, class_name, min_confidence, user, floor).subquery()
    n, points, low, mean = session.execute(
        select(func.count(), func.coalesce(func.sum(sub.c.n_points), 0), func.min(sub.c.predicted_confidence),
               func.avg(sub.c.predicted_confidence))
    ).one()
    largest = session.scalars(
        select(sub.c.id).order_by(sub.c.n_points.desc(), sub.c.id).limit(PREVIEW_TRACKS)
    ).all()
    return {"sequence_id": sequence_id, "class_name": class_name, "min_confidence": min_confidence,
            "tracks": int(n), "points": int(points), "confidence_min": None if low is None else float(low),
            "confidence_mean": None if mean is None else float(mean), "largest_track_ids": [int(i) for i in largest],
            "held_out_precision": precision, "held_out_tracks": support, "min_points": floor}


def held_out_precision(session: Session, sequence_id: int, class_name: str,
                       min_confidence: float) -> tuple[float | None, int, int | None]:
    """How often a reviewed track the newest model-in-the-loop run predicted as `class_name` at
    `min_confidence` or more was right with the track left out of the fit (app/jobs/assist.py),
    how many such tracks there were, and the points of the smallest of them (the bulk's size
    floor); (None, 0, None) before any run or when no track was so predicted."""
    for params, result in session.execute(
        select(Job.params, Job.result).where(Job.type == "assist", Job.status == "succeeded").order_by(Job.id.desc())
    ):
        if int(params.get("sequence_id", 0)) != sequence_id:
            continue
        held = (result or {}).get("held_out")
        if not held:
            return None, 0, None
        points = held.get("points") or [None] * len(held["truth"])
        picked = [(t == class_name, n) for t, p, c, n in zip(held["truth"], held["predicted"], held["confidence"],
                                                             points, strict=True)
                  if p == class_name and c >= min_confidence]
        if not picked:
            return None, 0, None
        sizes = [n for _, n in picked if n is not None]
        return round(sum(r for r, _ in picked) / len(picked), 4), len(picked), (min(sizes) if sizes else None)
    return None, 0, None


def bulk_accept(session: Session, sequence_id: int, user: AuthUser, class_name: str, min_confidence: float,
                expected_tracks: int | None = None) -> BulkAction:
    """Accept the candidates with `class_name` (see the module docstring). `expected_tracks`: the
    count the operator saw in the preview; a different count now (a retrain changed the
    predictions) is a Conflict and nothing changes. Commits."""
    label_set = _label_set(session, sequence_id, class_name)
    require_ready(session, sequence_id, "its tracks can be accepted once it is ready")
    floor = held_out_precision(session, sequence_id, class_name, min_confidence)[2]
    tracks = list(session.scalars(_candidates(sequence_id, class_name, min_confidence, user, floor)
                                  .with_for_update()).all())
    if expected_tracks is not None and expected_tracks != len(tracks):
        raise Conflict(f"{len(tracks)} tracks match now, not the {expected_tracks} previewed: the predictions "
                       "changed; preview again")
    if not tracks:
        raise Conflict(f"no pending track of sequence {sequence_id} is predicted {class_name} "
                       f"with confidence >= {min_confidence:g}")
    now = utcnow()
    bulk = BulkAction(sequence_id=sequence_id, user_id=user.id, class_name=class_name, min_confidence=min_confidence,
                      n_tracks=len(tracks), n_points=sum(t.n_points for t in tracks), created_at=now)
    session.add(bulk)
    session.flush()
    events = []
    for t in tracks:
        before = review_state(t)
        t.status, t.label, t.label_source = "accepted", class_name, "bulk"
        t.lease_user_id = t.lease_expires_at = None
        events.append(_event_row(t, user, "bulk_accept", before, {"bulk_id": bulk.id, "confidence": t.predicted_confidence},
                                 now))
        t.version += 1
        t.updated_at, t.reviewed_by_id = now, user.id
    session.flush()
    session.execute(insert(AnnotationEvent), events)
    for t in tracks:
        refresh_labels(session, t, user.id, label_set)
    session.commit()
    return bulk


def _event_row(track: Track, user: AuthUser, action: str, before: dict[str, Any], detail: dict[str, Any],
               now: Any, reverts: int | None = None) -> dict[str, Any]:
    return {"track_id": track.id, "user_id": user.id, "action": action, "created_at": now,
            "version_before": track.version, "version_after": track.version + 1, "before": before,
            "after": review_state(track), "detail": detail, "reverts_event_id": reverts}


def undo_bulk(session: Session, bulk_id: int, user: AuthUser) -> BulkAction:
    """Undo a whole bulk accept in one action: every track still as the bulk left it goes back
    to its state before (an `undo` event each, naming the bulk); tracks changed since (reviewed,
    undone one by one) keep their newer state. Conflict when already undone. Commits."""
    bulk = session.scalars(select(BulkAction).where(BulkAction.id == bulk_id).with_for_update()).first()
    if bulk is None:
        raise NotFound(f"bulk action {bulk_id} not found")
    if bulk.undone_at is not None:
        raise Conflict(f"bulk action {bulk_id} was undone already")
    now = utcnow()
    rows = session.execute(
        select(AnnotationEvent, Track).join(Track, Track.id == AnnotationEvent.track_id).where(
            AnnotationEvent.action == "bulk_accept", Track.sequence_id == bulk.sequence_id,
            AnnotationEvent.detail["bulk_id"].as_integer() == bulk_id)
        .order_by(Track.id).with_for_update(of=Track)
    ).all()
    undo_rows = []
    for ev, track in rows:
        if track.version != ev.version_after:
            continue  # changed since the bulk: the newer decision stays
        before = review_state(track)
        restored = stored_state(ev.before)
        for f in REVIEW_FIELDS:
            setattr(track, f, restored[f])
        undo_rows.append(_event_row(track, user, "undo", before, {"bulk_id": bulk_id}, now, reverts=ev.id))
        track.version += 1
        track.updated_at, track.reviewed_by_id = now, user.id
    session.flush()
    if undo_rows:
        session.execute(insert(AnnotationEvent), undo_rows)
    label_set = existing_label_set(session, bulk.sequence_id)  # the bulk cascades away with its sequence
    for _ev, track in rows:
        refresh_labels(session, track, user.id, label_set)
    bulk.undone_at, bulk.undone_by_id = now, user.id
    session.commit()
    return bulk


def list_bulk_actions(session: Session, sequence_id: int) -> list[BulkAction]:
    return list(session.scalars(
        select(BulkAction).where(BulkAction.sequence_id == sequence_id).order_by(BulkAction.id)).all())


def operation_count(session: Session, sequence_id: int) -> int:
    """Label-changing operations on a sequence's tracks, one per request: each review, repair and
    undo event counts once, except the second event of a merge (or of its undo), which records
    the same request on the other track, and the per-track events of a bulk accept or bulk undo,
    which count once through their `BulkAction` row (twice once undone); and each ground region
    drawn or deleted."""
    in_seq = select(Track.id).where(Track.sequence_id == sequence_id)
    compound = ("merge", "undo", "bulk_accept")
    simple = session.scalar(select(func.count()).select_from(AnnotationEvent).where(
        AnnotationEvent.track_id.in_(in_seq), AnnotationEvent.action.not_in(compound))) or 0
    events = session.execute(
        select(AnnotationEvent.id, AnnotationEvent.action, AnnotationEvent.detail, AnnotationEvent.reverts_event_id)
        .where(AnnotationEvent.track_id.in_(in_seq), AnnotationEvent.action.in_(compound))
    ).all()
    partner = {i for i, a, d, _ in events if a == "merge" and d and "into_track" in d}
    count = sum(
        1 for i, a, d, r in events
        if not (a == "bulk_accept" or (d and "bulk_id" in d) or i in partner or (a == "undo" and r in partner))
    )
    bulks = session.execute(
        select(func.count(), func.count(BulkAction.undone_at)).where(BulkAction.sequence_id == sequence_id)
    ).one()
    return int(simple) + count + int(bulks[0]) + int(bulks[1]) + region_operations(session, sequence_id)
