"""Stitches in the database: listing them and the operator's decision (confirm: the two tracks
show one object; reject: they do not). Routes: app/api/routes/stitches.py; rows are written by
ingest (app/jobs/ingest.py), and `crud.constraints_query` turns a confirmed stitch's fragment
pairs into verified constraints.

A decision locks the stitch row, checks its version (stale -> Conflict, nothing changes) and that
its sequence is ready, records the status, who and when, and bumps the version. A decision can be
changed later with the new version (an operator who confirmed by mistake rejects it).
"""

from __future__ import annotations

from typing import Any

from sqlalchemy import func, select
from sqlalchemy.orm import Session

from app import crud
from app.core.errors import NotFound, check_version
from app.crud import AuthUser, leases
from app.crud.rows import get_or_404
from app.models import Stitch, Track, utcnow

DECISIONS = {"confirm": "confirmed", "reject": "rejected"}


def list_stitches(
    session: Session,
    sequence_id: int | None,
    status: str | None,
    track_id: int | None,
    limit: int,
    offset: int,
) -> tuple[list[Stitch], int]:
    """Stitches filtered by sequence, status and track (either side), most links first."""
    where: list[Any] = []
    if sequence_id is not None:
        where.append(Stitch.sequence_id == sequence_id)
    if status is not None:
        where.append(Stitch.status == status)
    if track_id is not None:
        where.append((Stitch.track_a_id == track_id) | (Stitch.track_b_id == track_id))
    total = session.scalar(select(func.count()).select_from(Stitch).where(*where)) or 0
    items = session.scalars(
        select(Stitch).where(*where).order_by(Stitch.links.desc(), Stitch.id).limit(limit).offset(offset)
    ).all()
    return list(items), int(total)


def get_stitch(session: Session, stitch_id: int) -> Stitch:
    return get_or_404(session, Stitch, stitch_id, "stitch")


def decide_stitch(
    session: Session, stitch_id: int, user: AuthUser, decision: str, version: int,
    override_lease: bool = False, lease_seconds: float | None = None,
) -> Stitch:
    """Confirm or reject a stitch decided on `version` and commit. Unknown -> NotFound; stale
    version or a sequence that is not ready -> Conflict; either track leased to someone else ->
    LeaseHeld (app.crud.leases)."""
    st = session.scalars(select(Stitch).where(Stitch.id == stitch_id).with_for_update()).first()
    if st is None:
        raise NotFound(f"stitch {stitch_id} not found")
    crud.require_ready(session, st.sequence_id, "stitches can be decided once it is ready")
    check_version("stitch", stitch_id, version, st.version)
    now = utcnow()
    for track in session.scalars(
        select(Track).where(Track.id.in_((st.track_a_id, st.track_b_id))).order_by(Track.id).with_for_update()
    ):
        leases.check(session, track, user, now, override=override_lease, renew_seconds=lease_seconds)
    st.status = DECISIONS[decision]
    st.version += 1
    st.decided_by_id = user.id
    st.decided_at = utcnow()
    session.commit()
    return st
