"""Review actions on a track (`REVIEW_ACTIONS`: accept, discard, label, truncate, undo) and the labels
they materialise."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from sqlalchemy import DateTime, Integer, String, bindparam, delete, func, insert, select
from sqlalchemy.orm import Session

from app.core.errors import Conflict, Invalid, NotApplicable, NotFound, check_version
from app.crud import leases
from app.crud.datasets import require_ready
from app.crud.label_sets import check_class, existing_label_set
from app.crud.review_queue import queue_priority
from app.crud.tracks import track_events
from app.crud.users import AuthUser
from app.models import AnnotationEvent, Label, Segment, Track, utcnow
from app.schemas.tracks import (
    AcceptAction,
    ActionBase,
    DiscardAction,
    LabelAction,
    TruncateAction,
    UndoAction,
)
from pipeline.label_sets import LabelSet

REVIEW_FIELDS = ("status", "label", "keep_start", "keep_end", "label_source")


def review_state(track: Track) -> dict[str, Any]:
    """The part of a track that actions change (what events record before and after)."""
    return {f: getattr(track, f) for f in REVIEW_FIELDS}


def initial_review_state(track: Track) -> dict[str, Any]:
    """The state a track had when ingest created it."""
    return {"status": "pending", "label": None, "keep_start": track.first_frame, "keep_end": track.last_frame,
            "label_source": None}


def stored_state(recorded: dict[str, Any]) -> dict[str, Any]:
    """A review state as an event recorded it. Events written before label sources existed lack
    `label_source`: a class accepted then was an operator's own review."""
    state = {f: recorded.get(f) for f in REVIEW_FIELDS}
    if "label_source" not in recorded and state["status"] == "accepted" and state["label"] is not None:
        state["label_source"] = "review"
    return state


def rebuild_review_state(session: Session, track: Track) -> dict[str, Any]:
    """The review state replayed from the event log alone (it must equal `review_state(track)`).
    A merge widens a track's frame range; its event records the range before (`range_before`),
    so the replay starts from the range ingest gave the track."""
    events = track_events(session, track.id)
    state = initial_review_state(track)
    for ev in events:
        if ev.detail and "range_before" in ev.detail:
            state["keep_start"], state["keep_end"] = ev.detail["range_before"]
            break
    for ev in events:
        if stored_state(ev.before) != state:
            raise Conflict(f"event log of track {track.id} is inconsistent at event {ev.id}")
        state = stored_state(ev.after)
    return state


def apply_action(
    session: Session,
    track_id: int,
    user: AuthUser,
    action: str,
    version: int,
    *,
    override_lease: bool = False,
    lease_seconds: float | None = None,
    **fields: Any,
) -> Track:
    """Apply one review action (`REVIEW_ACTIONS`; `fields`: its body's fields, e.g. `label`) if
    `version` is current; write its event; commit.

    Stale version -> Conflict (nothing changes); a class not of the sequence's label set or a
    bad range -> Invalid; another user's running lease -> LeaseHeld (409; see app.crud.leases).
    The caller's own lease is renewed by `lease_seconds`.
    """
    track = _track_for_review(session, track_id, user, action, version, override_lease, lease_seconds)
    before = review_state(track)
    label_set = _label_set(session, track)
    after, reverts = _review_after(session, track, user, action, before, fields, label_set)
    if after["keep_start"] != before["keep_start"] or after["keep_end"] != before["keep_end"]:
        _recount_kept_range(session, track, after["keep_start"], after["keep_end"])

    now = utcnow()
    for f in REVIEW_FIELDS:
        setattr(track, f, after[f])
    track.version = version + 1
    track.updated_at = now
    track.reviewed_by_id = user.id
    if after["status"] != "pending":
        track.lease_user_id, track.lease_expires_at = None, None
    session.flush()  # the track's UPDATE
    session.connection().execute(
        _INSERT_EVENT,
        {
            "track_id": track_id, "user_id": user.id, "action": action, "created_at": now,
            "version_before": version, "version_after": version + 1, "before": before, "after": after,
            "reverts_event_id": None if reverts is None else reverts.id,
        },
    )
    refresh_labels(session, track, user.id, label_set)
    session.commit()
    return track


def _label_set(session: Session, track: Track) -> LabelSet:
    return existing_label_set(session, track.sequence_id)


def _track_for_review(
    session: Session, track_id: int, user: AuthUser, action: str, version: int, override_lease: bool,
    lease_seconds: float | None,
) -> Track:
    """The track, locked for update, once the action may go ahead: its sequence is ready, the
    lease allows it (renewing the caller's own), `version` is current and it is not merged away."""
    track = session.get(Track, track_id, with_for_update={"key_share": True})
    if track is None:
        raise NotFound(f"track {track_id} not found")
    require_ready(session, track.sequence_id, "tracks can be reviewed once it is ready")
    leases.check(session, track, user, utcnow(), override=override_lease, renew_seconds=lease_seconds)
    check_version("track", track_id, version, track.version)
    if track.status == "merged" and action != "undo":
        raise Conflict(f"track {track_id} was merged into another track; undo the merge first")
    return track


@dataclass
class ReviewStep:
    """What an action's rule sees: the locked track, the caller, the review state it changes in
    place (`after`, a copy of the state before) and the action's fields from its request body."""

    session: Session
    track: Track
    user: AuthUser
    after: dict[str, Any]
    fields: dict[str, Any]
    label_set: LabelSet  # the track's sequence's


def _accept(step: ReviewStep) -> None:
    step.after["status"] = "accepted"
    step.after["label_source"] = None if step.after["label"] is None else "review"


def _discard(step: ReviewStep) -> None:
    step.after["status"] = "discarded"
    step.after["label_source"] = None


def _label(step: ReviewStep) -> None:
    step.after["label"] = check_class("label", step.fields.get("label"), step.label_set)
    step.after["status"] = "accepted"  # labelling a track is accepting it with that class
    step.after["label_source"] = "review"


def _truncate(step: ReviewStep) -> None:
    start, end, track = step.fields["start"], step.fields["end"], step.track
    if not (track.first_frame <= start <= end <= track.last_frame):
        raise NotApplicable(
            f"frame range {start}..{end} is not inside the track's frames {track.first_frame}..{track.last_frame}"
        )
    step.after["keep_start"], step.after["keep_end"] = start, end


def _undo(step: ReviewStep) -> AnnotationEvent:
    reverts = last_undoable_event(step.session, step.track.id, step.user.id)
    if reverts is None:
        raise Conflict(f"nothing to undo: no action of {step.user.name} on track {step.track.id} is left to undo")
    was, became = stored_state(reverts.before), stored_state(reverts.after)
    for f in REVIEW_FIELDS:
        if was[f] != became[f]:
            step.after[f] = was[f]
    return reverts


@dataclass(frozen=True)
class ReviewAction:
    """One review action: its name (the event's `action`, `models.ACTIONS`), its request body,
    the OpenAPI text of its route (None: it has no route of its own here) and its rule, which
    changes `step.after` and returns the event an undo reverts (None for other actions)."""

    name: str
    body: type[ActionBase]
    route_doc: str | None
    rule: Callable[[ReviewStep], AnnotationEvent | None]


# The one list of review actions: the routes POST /tracks/{id}/<name> are made from it
# (app/api/routes/tracks.py), `apply_action` runs its rules, the assist job counts them. Undo's
# route is the repair's (app/api/routes/repair.py), which also undoes splits and merges.
REVIEW_ACTIONS: dict[str, ReviewAction] = {a.name: a for a in (
    ReviewAction("accept", AcceptAction, "Accept the track (its constraints become verified). Stale `version` -> 409.",
                 _accept),
    ReviewAction("discard", DiscardAction,
                 "Discard the track (a wrong association; its constraints are dropped). Stale `version` -> 409.", _discard),
    ReviewAction("truncate", TruncateAction,
                 "Keep frames `start..end` (inclusive) of the track's full range; outside it -> 409.", _truncate),
    ReviewAction("label", LabelAction, "Give the whole track one class of its sequence's label set (and accept "
                 "it); another class -> 422 naming the valid ones.",
                 _label),
    ReviewAction("undo", UndoAction, None, _undo),
)}


def _review_after(
    session: Session, track: Track, user: AuthUser, action: str, before: dict[str, Any], fields: dict[str, Any],
    label_set: LabelSet,
) -> tuple[dict[str, Any], AnnotationEvent | None]:
    """The review state after `action`, and the event an undo reverts (None for other actions)."""
    declared = REVIEW_ACTIONS.get(action)
    if declared is None:
        raise Invalid(f"unknown action {action!r}")
    step = ReviewStep(session, track, user, dict(before), fields, label_set)
    return step.after, declared.rule(step)


def _recount_kept_range(session: Session, track: Track, keep_start: int, keep_end: int) -> None:
    """Set the track's length (frames), samples, points and mean range (per segment) from its
    segments in `keep_start..keep_end` (what ingest computes over the whole track). A merged
    track can hold two segments in one frame: length counts frames, not segments. Invalid when
    none is kept."""
    segments, length, n_samples, n_points, range_sum = session.execute(
        select(
            func.count(),
            func.count(func.distinct(Segment.frame_index)),
            func.coalesce(func.sum(Segment.valid.cast(Integer)), 0),
            func.coalesce(func.sum(Segment.n_points), 0),
            func.coalesce(func.sum(Segment.range), 0.0),
        ).where(Segment.track_id == track.id, Segment.frame_index.between(keep_start, keep_end))
    ).one()
    if segments == 0:
        raise NotApplicable(f"frame range {keep_start}..{keep_end} keeps no segment of the track")
    track.length, track.n_samples = int(length), int(n_samples)
    track.n_points, track.mean_range = int(n_points), float(range_sum) / int(segments)
    track.priority = queue_priority(track.n_points, track.predicted_confidence)


def last_undoable_event(session: Session, track_id: int, user_id: int) -> AnnotationEvent | None:
    """The caller's latest non-undo event on the track that no undo has reverted yet."""
    reverted = select(AnnotationEvent.reverts_event_id).where(
        AnnotationEvent.track_id == track_id, AnnotationEvent.reverts_event_id.is_not(None)
    )
    return session.scalars(
        select(AnnotationEvent)
        .where(
            AnnotationEvent.track_id == track_id,
            AnnotationEvent.user_id == user_id,
            AnnotationEvent.action != "undo",
            AnnotationEvent.id.not_in(reverted),
        )
        .order_by(AnnotationEvent.id.desc())
        .limit(1)
    ).first()


# built once: an action runs these per call, and building a statement costs more than running it
_INSERT_EVENT = insert(AnnotationEvent.__table__)
_DELETE_LABELS = delete(Label.__table__).where(Label.__table__.c.track_id == bindparam("track_id"))
_INSERT_LABELS = insert(Label.__table__).from_select(
    ["sequence_id", "segment_id", "track_id", "class_name", "class_index", "source", "user_id", "created_at"],
    select(
        Segment.sequence_id,
        Segment.id,
        Segment.track_id,
        bindparam("class_name", type_=String),
        bindparam("class_index", type_=Integer),
        bindparam("source", type_=String),
        bindparam("user_id", type_=Integer),
        bindparam("created_at", type_=DateTime),
    ).where(
        Segment.track_id == bindparam("track_id"),
        Segment.valid.is_(True),
        Segment.frame_index.between(bindparam("keep_start"), bindparam("keep_end")),
    ),
)


def refresh_labels(session: Session, track: Track, user_id: int, label_set: LabelSet) -> None:
    """Materialise the labelled samples of a track: its valid segments in the kept range when it is
    accepted with a class (indexed in `label_set`, its sequence's); none otherwise. (Core statements on the session's connection: no
    Label object is loaded in an action's session, so the ORM has nothing to synchronise.)"""
    conn = session.connection()
    conn.execute(_DELETE_LABELS, {"track_id": track.id})
    if track.status != "accepted" or track.label is None:
        return
    conn.execute(
        _INSERT_LABELS,
        {
            "track_id": track.id, "class_name": track.label, "class_index": label_set.sample_class_names.index(track.label),
            "source": track.label_source or "review",
            "user_id": user_id, "created_at": utcnow(), "keep_start": track.keep_start, "keep_end": track.keep_end,
        },
    )


def review_events_after(session: Session, sequence_id: int, actions: tuple[str, ...], after: int) -> tuple[int, int]:
    """(count, newest id, 0 when none) of the sequence's annotation events with one of `actions`
    and an id above `after`."""
    n, newest = session.execute(
        select(func.count(), func.coalesce(func.max(AnnotationEvent.id), 0))
        .join(Track, Track.id == AnnotationEvent.track_id)
        .where(Track.sequence_id == sequence_id, AnnotationEvent.action.in_(actions), AnnotationEvent.id > after)
    ).one()
    return int(n), int(newest)
