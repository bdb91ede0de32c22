"""The quality stage: accepted tracks sampled into an audit queue, and the auditor's verdicts.

An admin or a reviewer samples `n` accepted tracks that were never audited (uniformly at random,
seeded); each audit remembers the operator who accepted the track and the class they gave. The
auditor agrees, or corrects the class: the correction is applied to the track as a `label`
action (its event, its label rows, the lease check) in the same transaction. Agreement per
operator and per class goes into `/exports/stats`.
"""

from __future__ import annotations

import math
import random
from typing import Any

from sqlalchemy import Integer, func, or_, select
from sqlalchemy.orm import Session

from app import crud
from app.core.errors import Conflict, NotFound
from app.crud import AuthUser
from app.models import AnnotationEvent, Audit, BulkAction, Track, User, utcnow

DISCARD = "(discard)"  # the auditor's verdict that an audited track is no object


def sample_audits(session: Session, user: AuthUser, n: int, sequence_id: int | None, seed: int,
                  source: str | None = None) -> list[Audit]:
    """Queue up to `n` accepted, never-audited tracks (of one sequence or all; only those whose
    class came from `source` when given, e.g. `bulk`). Commits."""
    audited = select(Audit.track_id)
    where = [Track.status == "accepted", Track.id.not_in(audited)]
    if sequence_id is not None:
        where.append(Track.sequence_id == sequence_id)
    if source is not None:
        where.append(Track.label_source == source)
    candidates = list(session.scalars(select(Track.id).where(*where).order_by(Track.id)).all())
    picked = sorted(random.Random(seed).sample(candidates, min(n, len(candidates))))
    audits = []
    for track in session.scalars(select(Track).where(Track.id.in_(picked)).order_by(Track.id)):
        audits.append(Audit(sequence_id=track.sequence_id, track_id=track.id, operator_id=track.reviewed_by_id,
                            label=track.label, status="queued", sampled_by_id=user.id, source=track.label_source,
                            bulk_id=_bulk_of(session, track) if track.label_source == "bulk" else None))
    session.add_all(audits)
    session.commit()
    return audits


def _bulk_of(session: Session, track: Track) -> int | None:
    """The bulk accept that gave the track its class (its newest bulk_accept event)."""
    ev = session.scalars(select(AnnotationEvent).where(AnnotationEvent.track_id == track.id,
                                                       AnnotationEvent.action == "bulk_accept")
                         .order_by(AnnotationEvent.id.desc()).limit(1)).first()
    return None if ev is None or not ev.detail else int(ev.detail["bulk_id"])


def decide_audit(
    session: Session,
    audit_id: int,
    user: AuthUser,
    label: str | None,
    override_lease: bool = False,
    lease_seconds: float | None = None,
) -> Audit:
    """Agree (`label` None, or the operator's own class) or correct the class of an audited track;
    `label` DISCARD: the track is no object of any class (ground, noise) and is discarded.
    NotFound / Conflict when it is decided already or the track is no longer accepted. Commits."""
    audit = session.scalars(select(Audit).where(Audit.id == audit_id).with_for_update()).first()
    if audit is None:
        raise NotFound(f"audit {audit_id} not found")
    if audit.status != "queued":
        raise Conflict(f"audit {audit_id} is already {audit.status}")
    track = crud.get_track(session, audit.track_id)
    if track.status != "accepted":
        raise Conflict(f"track {track.id} is {track.status} now; it left the audit's scope")
    audit.auditor_id, audit.decided_at = user.id, utcnow()
    if label is None or label == audit.label:
        audit.status, audit.answer_label = "agreed", audit.label
        session.commit()
        return audit
    audit.status, audit.answer_label = "corrected", None if label == DISCARD else label
    action, kw = ("discard", {}) if label == DISCARD else ("label", {"label": label})
    crud.apply_action(session, track.id, user, action, track.version,
                      override_lease=override_lease, lease_seconds=lease_seconds, **kw)  # commits both
    return audit


def audit_stats(session: Session, sequence_id: int | None) -> dict[str, Any]:
    """Decided audits and the share agreed, per operator (by name) and per operator's class."""
    where = [Audit.status != "queued"] + ([] if sequence_id is None else [Audit.sequence_id == sequence_id])
    agreed = func.sum((Audit.status == "agreed").cast(Integer))
    rows_op = session.execute(
        select(func.coalesce(User.name, "(deleted)"), func.count(), agreed)
        .select_from(Audit).outerjoin(User, User.id == Audit.operator_id).where(*where).group_by(User.name)
    ).all()
    rows_cls = session.execute(
        select(func.coalesce(Audit.label, "(none)"), func.count(), agreed).where(*where).group_by(Audit.label)
    ).all()
    queued = session.scalar(
        select(func.count()).select_from(Audit).where(
            Audit.status == "queued", *([] if sequence_id is None else [Audit.sequence_id == sequence_id]))
    ) or 0

    def table(rows: list[Any]) -> dict[str, dict[str, float]]:
        return {str(k): {"audited": int(n), "agreed": int(a or 0), "agreement": round(int(a or 0) / int(n), 4)}
                for k, n, a in rows}

    return {"queued": int(queued), "per_operator": table(rows_op), "per_class": table(rows_cls),
            "bulk": bulk_error(session, sequence_id)}


def wilson_interval(errors: int, n: int, z: float = 1.96) -> tuple[float, float]:
    """The 95 % Wilson score interval of a proportion `errors / n` ((0, 1) when n is 0): honest
    at 0 or n errors, where the normal interval collapses to a point."""
    if n == 0:
        return 0.0, 1.0
    p = errors / n
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    return max(0.0, centre - half), min(1.0, centre + half)


def bulk_error(session: Session, sequence_id: int | None) -> dict[str, Any]:
    """The measured error of bulk-accepted classes: per class, the share of audited bulk tracks
    the auditor corrected, with its 95 % Wilson interval; overall, the same over every audited
    bulk track (audits draw uniformly among the bulk-accepted tracks, so the pooled share
    estimates the error of the tracks accepted in bulk). Audits of a bulk accept that was undone
    since are left out: its tracks carry no bulk class any more."""
    undone = select(BulkAction.id).where(BulkAction.undone_at.is_not(None))
    where = [Audit.status != "queued", Audit.source == "bulk", or_(Audit.bulk_id.is_(None), Audit.bulk_id.not_in(undone))]
    if sequence_id is not None:
        where.append(Audit.sequence_id == sequence_id)
    corrected = func.sum((Audit.status == "corrected").cast(Integer))
    rows = session.execute(select(Audit.label, func.count(), corrected).where(*where).group_by(Audit.label)).all()
    t_where = [Track.status == "accepted", Track.label_source == "bulk"]
    if sequence_id is not None:
        t_where.append(Track.sequence_id == sequence_id)
    accepted = {str(k): int(v) for k, v in
                session.execute(select(Track.label, func.count()).where(*t_where).group_by(Track.label)).all()}

    def rate(wrong: int, n: int) -> dict[str, Any]:
        lo, hi = wilson_interval(wrong, n)
        return {"audited": n, "corrected": wrong, "error": round(wrong / n, 4) if n else None,
                "ci95": [round(lo, 4), round(hi, 4)]}

    per_class = {str(c): rate(int(w or 0), int(n)) | {"bulk_tracks": accepted.get(str(c), 0)} for c, n, w in rows}
    overall = rate(sum(v["corrected"] for v in per_class.values()), sum(v["audited"] for v in per_class.values()))
    return {"bulk_tracks": sum(accepted.values()), "bulk_tracks_per_class": accepted, "per_class": per_class,
            "overall": overall}


def list_audits(session: Session, status: str | None, sequence_id: int | None, limit: int, offset: int) -> list[Audit]:
    """Audits, oldest first (of one status and sequence when given)."""
    q = select(Audit).order_by(Audit.id).limit(limit).offset(offset)
    if status is not None:
        q = q.where(Audit.status == status)
    if sequence_id is not None:
        q = q.where(Audit.sequence_id == sequence_id)
    return list(session.scalars(q).all())
