"""Annotated dependencies shared by the routes: sessions, settings, artifacts, the caller."""

from __future__ import annotations

from collections.abc import AsyncIterator
from dataclasses import dataclass
from typing import Annotated

from fastapi import Depends, HTTPException, Path, Query, Request, status
from fastapi.concurrency import run_in_threadpool
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer
from sqlalchemy.orm import Session

from app import crud
from app.api.retry import retrying
from app.artifacts import ArtifactStore
from app.core.config import Settings
from app.core.db import Database
from app.crud import AuthUser, leases
from app.models import Track, utcnow

MAX_ID = 2**31 - 1  # INTEGER primary keys (users, datasets, sequences, frames, jobs)
MAX_BIG_ID = 2**62  # BIGINT primary keys (tracks, segments)

bearer = HTTPBearer(auto_error=False, description="`Authorization: Bearer <token>` from `tracklabel user add`.")


# Dependencies that do no I/O are `async def`: FastAPI runs sync dependencies in its thread pool,
# and a hop per dependency costs more than the dependency itself. A Session does no I/O until it is
# used (inside the sync route, in the pool), nor when it is closed with no transaction left open
# on the database: then it is closed right here.


async def get_database(request: Request) -> Database:
    return request.app.state.db


async def get_settings_dep(request: Request) -> Settings:
    return request.app.state.settings


async def get_artifacts(request: Request) -> ArtifactStore:
    return request.app.state.artifacts


async def get_read_session(db: Annotated[Database, Depends(get_database)]) -> AsyncIterator[Session]:
    session = db.read()
    try:
        yield session
    finally:
        # PostgreSQL reads run in autocommit, and ending SQLite's read transaction is a local call
        session.close()


async def get_write_session(db: Annotated[Database, Depends(get_database)]) -> AsyncIterator[Session]:
    session = db.write()
    try:
        yield session
    finally:
        if session.in_transaction():  # a route that failed: its ROLLBACK is a round trip
            await run_in_threadpool(session.close)
        else:
            session.close()


DatabaseDep = Annotated[Database, Depends(get_database)]
SettingsDep = Annotated[Settings, Depends(get_settings_dep)]
ArtifactsDep = Annotated[ArtifactStore, Depends(get_artifacts)]
SessionDep = Annotated[Session, Depends(get_read_session)]
WriteSessionDep = Annotated[Session, Depends(get_write_session)]


async def get_current_user(
    request: Request,
    db: DatabaseDep,
    credentials: Annotated[HTTPAuthorizationCredentials | None, Depends(bearer)],
) -> AuthUser:
    """The caller named by a valid bearer token; 401 otherwise, 429 while the client's address
    is over the limit of invalid tokens (app/api/security.py). Uses its own short read session.

    Looked up on every request, never cached: a revoked or expired token, or a disabled user, is
    refused from the next request on, whichever process (CLI, another API worker) changed it."""
    if credentials is None or credentials.scheme.lower() != "bearer" or not credentials.credentials:
        raise HTTPException(status.HTTP_401_UNAUTHORIZED, "missing bearer token", {"WWW-Authenticate": "Bearer"})
    limit = request.app.state.auth_limit
    address = request.client.host if request.client else "unknown"
    wait = limit.retry_after(address)
    if wait:
        raise HTTPException(status.HTTP_429_TOO_MANY_REQUESTS,
                            f"too many invalid tokens from this address; retry in {wait} s", {"Retry-After": str(wait)})
    user = await run_in_threadpool(_lookup_token, db, credentials.credentials)
    if user is None:
        limit.failed(address)
        raise HTTPException(
            status.HTTP_401_UNAUTHORIZED, "invalid, expired or revoked token", {"WWW-Authenticate": "Bearer"}
        )
    return user


CurrentUser = Annotated[AuthUser, Depends(get_current_user)]


@retrying
def _lookup_token(db: Database, token: str) -> AuthUser | None:
    with db.connect_read() as conn:  # a bare connection: a Session would cost more than the query
        return crud.user_for_token(conn, token)


async def require_admin(user: CurrentUser) -> AuthUser:
    if not user.is_admin:
        raise HTTPException(status.HTTP_403_FORBIDDEN, "admin role required")
    return user


async def require_auditor(user: CurrentUser) -> AuthUser:
    if user.role not in ("admin", "reviewer"):
        raise HTTPException(status.HTTP_403_FORBIDDEN, "admin or reviewer role required")
    return user


AdminUser = Annotated[AuthUser, Depends(require_admin)]
AuditorUser = Annotated[AuthUser, Depends(require_auditor)]


@dataclass(frozen=True)
class LeaseGuard:
    """The caller, their explicit lease override and the lease length: what `app.crud.leases.check`
    needs besides the session and the locked track. A route that changes a track takes
    `guard: LeaseGuardDep` and calls `guard.check(session, track)`."""

    user: AuthUser
    override: bool
    lease_seconds: float

    def check(self, session: Session, track: Track, renew: bool = True) -> None:
        """409 unless the caller may change the track now; renews the caller's own lease unless
        `renew` is False (a check in a read session, which must not write)."""
        leases.check(session, track, self.user, utcnow(), override=self.override,
                     renew_seconds=self.lease_seconds if renew else None)


async def get_lease_guard(
    user: CurrentUser,
    settings: SettingsDep,
    override_lease: Annotated[
        bool, Query(description="Admins only: act on a track another user holds the lease of.")
    ] = False,
) -> LeaseGuard:
    if override_lease and not user.is_admin:
        raise HTTPException(status.HTTP_403_FORBIDDEN, "override_lease needs the admin role")
    return LeaseGuard(user, override_lease, settings.review_lease_seconds)


LeaseGuardDep = Annotated[LeaseGuard, Depends(get_lease_guard)]

IdPath = Annotated[int, Path(ge=1, le=MAX_ID)]
BigIdPath = Annotated[int, Path(ge=1, le=MAX_BIG_ID)]
