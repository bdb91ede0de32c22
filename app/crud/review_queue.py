"""The review queue: leasing the next track to an operator."""

from __future__ import annotations

from datetime import datetime, timedelta
from typing import Any

from sqlalchemy import or_, select, update
from sqlalchemy.orm import Session
from sqlalchemy.orm.attributes import set_committed_value

from app.core.errors import NotFound
from app.crud.leases import LeaseHeld
from app.crud.users import AuthUser
from app.models import Sequence, Track, User, utcnow


def queue_priority(n_points: int, confidence: float | None) -> float:
    """A pending track's place in the queue (highest first): the points its review is expected to
    correct, i.e. all of them before the model has predicted it, else the share the model may have
    wrong (1 - its confidence). Large tracks the model is unsure of come first: reviewing them
    labels the most points the export would otherwise get wrong, and teaches the model where it
    errs (docs/effort.md measures the orders)."""
    return float(n_points) * (1.0 - float(confidence)) if confidence is not None else float(n_points)


QUEUE_ORDERS = {"priority": Track.priority, "size": Track.n_points}


def _unleased(now: datetime) -> Any:
    """SQL condition: the track has no lease running at `now` (none, or an expired one)."""
    return or_(Track.lease_expires_at.is_(None), Track.lease_expires_at < now)


def lease_next_track(
    session: Session,
    user: AuthUser,
    lease_seconds: float,
    sequence_id: int | None = None,
    exclude: tuple[int, ...] = (),
    order: str = "priority",
) -> Track | None:
    """Lease a pending track of a ready sequence to `user`: their own live lease first, else the
    unleased (or lease-expired) pending track of the highest `queue_priority` (`order` "size": the
    one with the most points). Tracks in `exclude` are passed over (one user's other viewer tabs
    hold them, or the operator skipped them); among equal priorities the newest track first. Commits."""
    now = utcnow()
    expires = now + timedelta(seconds=lease_seconds)
    ready = select(Sequence.id).where(Sequence.status == "ready")
    base = [Track.status == "pending", Track.sequence_id.in_(ready)]
    if sequence_id is not None:
        base.append(Track.sequence_id == sequence_id)
    if exclude:
        base.append(Track.id.not_in(exclude))
    own = session.scalars(
        select(Track)
        .where(*base, Track.lease_user_id == user.id, Track.lease_expires_at > now)
        .order_by(Track.id)
        .limit(1)
        .with_for_update()
    ).first()
    track = own
    for _ in range(5):
        if track is not None:
            break
        cand = session.scalars(
            select(Track)
            .where(*base, _unleased(now))
            # both descending: one direction, so the queue index (..., priority, id) is read
            # backwards and stops at the first free track (id ascending sorted every tie first)
            .order_by(QUEUE_ORDERS[order].desc(), Track.id.desc())
            .limit(1)
            .with_for_update(skip_locked=True)
        ).first()
        if cand is None:
            session.rollback()
            return None
        # Conditional update: only wins if nobody leased it since we read it.
        res = session.execute(
            update(Track)
            .where(
                Track.id == cand.id,
                Track.status == "pending",
                _unleased(now),
            )
            .values(lease_user_id=user.id, lease_expires_at=expires)
            .execution_options(synchronize_session=False)
        )
        if res.rowcount == 1:
            track = cand
            # what the update wrote, as loaded state: set as a change, the flush would write it again
            set_committed_value(track, "lease_user_id", user.id)
            set_committed_value(track, "lease_expires_at", expires)
    if track is None:
        session.rollback()
        return None
    track.lease_expires_at = expires  # renews the caller's own lease (a no-op for a new one)
    session.commit()
    return track


def lease_track(session: Session, track_id: int, user: AuthUser, lease_seconds: float) -> Track:
    """Lease one chosen track to `user` (a track opened out of queue order, or brought back by
    undo), so that the queue does not hand it to someone else meanwhile. A reviewed track needs no
    lease and is returned as it is. NotFound for an unknown track; Conflict while another user's
    lease on it runs. Commits."""
    now = utcnow()
    track = session.get(Track, track_id)
    if track is None:
        raise NotFound(f"track {track_id} not found")
    if track.status != "pending":
        return track
    res = session.execute(
        update(Track)
        .where(
            Track.id == track_id,
            or_(Track.lease_user_id == user.id, _unleased(now)),
        )
        .values(lease_user_id=user.id, lease_expires_at=now + timedelta(seconds=lease_seconds))
        .execution_options(synchronize_session=False)
    )
    if res.rowcount != 1:
        session.rollback()
        holder = session.get(Track, track_id)
        name = session.scalar(select(User.name).where(User.id == holder.lease_user_id)) if holder else None
        raise LeaseHeld(track_id, name or "another user", (holder and holder.lease_expires_at) or now)  # the 409 of app.crud.leases
    session.commit()
    session.refresh(track)
    return track


def release_lease(session: Session, track_id: int, user: AuthUser) -> None:
    """Give back the caller's lease on a track (no-op when they hold none). Commits."""
    session.execute(
        update(Track)
        .where(Track.id == track_id, Track.lease_user_id == user.id)
        .values(lease_user_id=None, lease_expires_at=None)
    )
    session.commit()
