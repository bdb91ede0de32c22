"""Anchor proposals in the database: listing them, the operator's answers, and the anchors a
fine-tune job trains on. Routes (app/api/routes/anchors.py) and jobs (app/jobs/anchors.py,
app/jobs/finetune.py) call these.

An answer locks the proposal row, checks it is still `proposed` (else Conflict), records the
answer and an `anchor_events` row with the operator, and commits. Confirming or correcting a
track-level proposal also labels its track through `crud.apply_action("label")`, the same path
the review actions take (its event, its label rows), in the same transaction.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from sqlalchemy import delete, func, insert, select
from sqlalchemy.orm import Session

from app import crud
from app.core.errors import Conflict, Invalid, NotApplicable, NotFound
from app.crud import AuthUser
from app.crud.label_sets import check_class, existing_label_set
from app.models import AnchorEvent, AnchorProposal, Frame, Segment, Track, User, utcnow

ANSWERS = ("confirm", "correct", "reject")


@dataclass(frozen=True)
class AnchorFilter:
    sequence_id: int | None = None
    status: str | None = None
    level: str | None = None
    strategy: str | None = None
    proposed_class: str | None = None
    track_id: int | None = None

    def clauses(self) -> list[Any]:
        c: list[Any] = []
        for col, value in (
            (AnchorProposal.sequence_id, self.sequence_id),
            (AnchorProposal.status, self.status),
            (AnchorProposal.level, self.level),
            (AnchorProposal.strategy, self.strategy),
            (AnchorProposal.proposed_class, self.proposed_class),
            (AnchorProposal.track_id, self.track_id),
        ):
            if value is not None:
                c.append(col == value)
        return c


def _rows_query() -> Any:
    return (
        select(AnchorProposal, Segment.frame_index, User.name)
        .outerjoin(Segment, Segment.id == AnchorProposal.segment_id)
        .outerjoin(User, User.id == AnchorProposal.decided_by_id)
    )


def anchor_dict(p: AnchorProposal, frame_index: int | None, decided_by: str | None) -> dict[str, Any]:
    """The public view of a proposal (app.schemas.AnchorPublic)."""
    return {
        "id": p.id,
        "sequence_id": p.sequence_id,
        "track_id": p.track_id,
        "segment_id": p.segment_id,
        "frame_index": frame_index,
        "level": p.level,
        "strategy": p.strategy,
        "rank": p.rank,
        "proposed_class": p.proposed_class,
        "score": p.score,
        "status": p.status,
        "answer_class": p.answer_class,
        "corrected": p.status == "confirmed" and p.answer_class != p.proposed_class,
        "decided_by_id": p.decided_by_id,
        "decided_by": decided_by,
        "decided_at": p.decided_at,
        "model_id": p.model_version_id,
        "job_id": p.job_id,
        "created_at": p.created_at,
        "sample_url": None if p.segment_id is None else f"/api/v1/segments/{p.segment_id}/sample.png",
    }


def list_anchors(session: Session, flt: AnchorFilter, limit: int, offset: int) -> tuple[list[dict[str, Any]], int]:
    """A page of proposals (by id: class by class, best first within a class) and the total."""
    clauses = flt.clauses()
    rows = session.execute(
        _rows_query().where(*clauses).order_by(AnchorProposal.id).limit(limit).offset(offset)
    ).all()
    total = session.scalar(select(func.count()).select_from(AnchorProposal).where(*clauses)) or 0
    return [anchor_dict(*r) for r in rows], int(total)


def get_anchor(session: Session, anchor_id: int) -> dict[str, Any]:
    row = session.execute(_rows_query().where(AnchorProposal.id == anchor_id)).first()
    if row is None:
        raise NotFound(f"anchor proposal {anchor_id} not found (it may have been replaced by a newer proposal run)")
    return anchor_dict(*row)


def anchor_summary(session: Session, sequence_id: int | None) -> dict[str, Any]:
    """Counts by status and per class: proposed (by proposed class), confirmed (by answer class),
    corrected, rejected."""
    where = [] if sequence_id is None else [AnchorProposal.sequence_id == sequence_id]
    rows = session.execute(
        select(AnchorProposal.status, AnchorProposal.proposed_class, AnchorProposal.answer_class, func.count())
        .where(*where)
        .group_by(AnchorProposal.status, AnchorProposal.proposed_class, AnchorProposal.answer_class)
    ).all()
    by_status: dict[str, int] = {}
    per_class: dict[str, dict[str, int]] = {}

    def bump(cls: str | None, key: str, n: int) -> None:
        if cls is None:
            return
        entry = per_class.setdefault(cls, {"proposed": 0, "confirmed": 0, "corrected": 0, "rejected": 0})
        entry[key] += n

    for status, proposed, answer, n in rows:
        by_status[status] = by_status.get(status, 0) + int(n)
        if status == "proposed":
            bump(proposed, "proposed", int(n))
        elif status == "rejected":
            bump(proposed, "rejected", int(n))
        else:
            bump(answer, "confirmed", int(n))
            if answer != proposed:
                bump(proposed, "corrected", int(n))
    return {"total": sum(by_status.values()), "by_status": by_status, "per_class": per_class}


def anchor_events(session: Session, anchor_id: int) -> list[AnchorEvent]:
    if session.get(AnchorProposal, anchor_id) is None:
        raise NotFound(f"anchor proposal {anchor_id} not found")
    return list(
        session.scalars(select(AnchorEvent).where(AnchorEvent.proposal_id == anchor_id).order_by(AnchorEvent.id)).all()
    )


def answer_anchor(
    session: Session,
    anchor_id: int,
    user: AuthUser,
    answer: str,
    label: str | None = None,
) -> dict[str, Any]:
    """Confirm (the proposed class), correct (to `label`) or reject a proposal. Commits.

    Unknown proposal -> NotFound; already answered -> Conflict; a class not of the sequence's
    label set -> Invalid. A
    track-level confirmation labels the track (Conflict when the track was discarded meanwhile
    or its sequence is not ready).
    """
    if answer not in ANSWERS:
        raise Invalid(f"unknown answer {answer!r}; valid: {', '.join(ANSWERS)}")
    p = session.scalars(select(AnchorProposal).where(AnchorProposal.id == anchor_id).with_for_update()).first()
    if p is None:
        raise NotFound(f"anchor proposal {anchor_id} not found (it may have been replaced by a newer proposal run)")
    if p.status != "proposed":
        who = session.scalar(select(User.name).where(User.id == p.decided_by_id)) if p.decided_by_id else None
        raise Conflict(f"anchor proposal {anchor_id} is already {p.status}" + (f" by {who}" if who else ""))
    label_set = existing_label_set(session, p.sequence_id)  # a proposal cascades away with its sequence
    if answer == "confirm":
        cls = p.proposed_class
        if cls not in label_set.sample_class_names:
            raise NotApplicable(f"proposal {anchor_id} has no valid proposed class ({cls!r}); correct it instead")
    elif answer == "correct":
        cls = check_class("label", label, label_set)
    else:
        cls = None
    track: Track | None = None
    if p.level == "track" and cls is not None:
        track = session.scalars(select(Track).where(Track.id == p.track_id).with_for_update()).first()
        if track is None:  # pragma: no cover - the proposal cascades away with its track
            raise NotFound(f"track {p.track_id} not found")
        if track.status == "discarded":
            raise Conflict(f"track {track.id} was discarded after it was proposed; it cannot be labelled as a whole")
    now = utcnow()
    p.status = "rejected" if answer == "reject" else "confirmed"
    p.answer_class = cls
    p.decided_by_id = user.id
    p.decided_at = now
    session.add(
        AnchorEvent(
            proposal_id=p.id, sequence_id=p.sequence_id, user_id=user.id, action=answer, class_name=cls, created_at=now
        )
    )
    session.flush()
    if track is not None:
        # commits the proposal, its event and the track's label together
        crud.apply_action(session, track.id, user, "label", track.version, label=cls)
    else:
        session.commit()
    return get_anchor(session, anchor_id)


def confirmed_sample_anchors(session: Session, sequence_id: int) -> list[tuple[int, str]]:
    """(segment id, class) of the sequence's confirmed sample-level anchors (track-level ones
    are in the labels table through their track)."""
    return [
        (int(seg), str(cls))
        for seg, cls in session.execute(
            select(AnchorProposal.segment_id, AnchorProposal.answer_class).where(
                AnchorProposal.sequence_id == sequence_id,
                AnchorProposal.status == "confirmed",
                AnchorProposal.level == "sample",
                AnchorProposal.segment_id.is_not(None),
            )
        ).all()
    ]


def proposal_candidates(session: Session, sequence_id: int) -> list[Any]:
    """The sequence's segments that have a sample and a track, in frame order then local id, with
    their frame's artifact and their track's status and label: (id, track_id, sample_index,
    artifact, status, label)."""
    return list(session.execute(
        select(Segment.id, Segment.track_id, Segment.sample_index, Frame.artifact, Track.status, Track.label)
        .join(Frame, Frame.id == Segment.frame_id)
        .join(Track, Track.id == Segment.track_id)
        .where(Segment.sequence_id == sequence_id, Segment.sample_index.is_not(None))
        .order_by(Segment.frame_index, Segment.local_id)
    ).all())


def answered_proposals(session: Session, sequence_id: int, *, with_unanswered: bool) -> list[Any]:
    """(segment_id, track_id, level) of the sequence's answered proposals, and of its unanswered
    ones too with `with_unanswered` (a run that keeps them must not propose them again)."""
    q = select(AnchorProposal.segment_id, AnchorProposal.track_id, AnchorProposal.level).where(
        AnchorProposal.sequence_id == sequence_id
    )
    if not with_unanswered:
        q = q.where(AnchorProposal.status != "proposed")
    return list(session.execute(q).all())


def store_proposals(session: Session, sequence_id: int, values: list[dict[str, Any]], *, replace: bool) -> int:
    """Insert proposal rows, first deleting the sequence's unanswered ones with `replace`; commits.
    Returns how many were deleted."""
    removed = 0
    if replace:
        removed = session.execute(
            delete(AnchorProposal).where(AnchorProposal.sequence_id == sequence_id, AnchorProposal.status == "proposed")
        ).rowcount
    if values:
        session.execute(insert(AnchorProposal), values)
    session.commit()
    return int(removed or 0)
