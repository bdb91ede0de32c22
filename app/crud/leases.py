"""Track leases, enforced: the one check every track-changing action runs.

`POST /review/next` (or `/review/{id}/lease`) leases a pending track to one operator for
`review_lease_seconds`. While that lease runs, nobody else may change the track: an action by
anyone else is refused with 409 naming the holder, unless the caller is an admin who asked to
override (`?override_lease=true`). The holder's own actions renew the lease; an expired lease
binds nobody.

A route that changes a track calls `check` inside its write transaction, after locking the
track row (so the lease it reads cannot change before the commit):

    track = session.get(Track, track_id, with_for_update=True)
    leases.check(session, track, user, utcnow(), override=..., renew_seconds=settings.review_lease_seconds)

With `LeaseGuardDep` (app.api.deps) the route takes the caller, the override flag and the lease
length in one parameter and calls `guard.check(session, track)`.
"""

from __future__ import annotations

from datetime import datetime, timedelta
from typing import TYPE_CHECKING

from sqlalchemy import select
from sqlalchemy.orm import Session

from app.core.errors import Conflict, Forbidden
from app.models import Track, User

if TYPE_CHECKING:
    from app.crud import AuthUser


class LeaseHeld(Conflict):
    """Another user's lease on the track runs (409); `holder` names them."""

    def __init__(self, track_id: int, holder: str, until: datetime) -> None:
        super().__init__(
            f"track {track_id} is leased to {holder} until {until.isoformat(timespec='seconds')}Z; "
            "an admin may override with override_lease=true"
        )
        self.holder = holder


def holder_name(session: Session, track: Track) -> str:
    """The name of the user holding the track's lease ('another user' when they are gone)."""
    name = session.scalar(select(User.name).where(User.id == track.lease_user_id))
    return name or "another user"


def check(
    session: Session,
    track: Track,
    user: AuthUser,
    now: datetime,
    *,
    override: bool = False,
    renew_seconds: float | None = None,
) -> None:
    """Refuse `user`'s change of `track` while another user's lease on it runs.

    - no lease, an expired one, or the caller's own: allowed; the caller's own running lease is
      renewed to `now + renew_seconds` (when given);
    - another user's running lease: LeaseHeld (409) naming the holder, unless `override` and the
      caller is an admin; `override` from a non-admin is Forbidden (403).

    `track` should be locked (`with_for_update`) by the caller's transaction; nothing is committed.
    """
    if override and not user.is_admin:
        raise Forbidden("override_lease needs the admin role")
    running = track.lease_user_id is not None and track.lease_expires_at is not None and track.lease_expires_at > now
    if not running:
        return
    if track.lease_user_id == user.id:
        if renew_seconds is not None:
            track.lease_expires_at = now + timedelta(seconds=renew_seconds)
        return
    if override:
        return
    assert track.lease_expires_at is not None
    raise LeaseHeld(track.id, holder_name(session, track), track.lease_expires_at)
