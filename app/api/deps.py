"""Annotated dependencies shared by the routes: sessions, settings, artifacts, the caller."""

from __future__ import annotations

import threading
import time
from collections.abc import AsyncIterator
from typing import Annotated

from fastapi import Depends, HTTPException, Path, Request, status
from fastapi.concurrency import run_in_threadpool
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer
from sqlalchemy.orm import Session

from app import crud
from app.artifacts import ArtifactStore
from app.core.config import Settings
from app.core.db import Database
from app.crud import AuthUser

MAX_ID = 2**31 - 1  # INTEGER primary keys (users, datasets, sequences, frames, jobs)
MAX_BIG_ID = 2**62  # BIGINT primary keys (tracks, segments)

bearer = HTTPBearer(auto_error=False, description="`Authorization: Bearer <token>` from `tracklabel user add`.")


# Dependencies that do no I/O are `async def`: FastAPI runs sync dependencies in its thread pool,
# and a hop per dependency costs more than the dependency itself. A Session does no I/O until it is
# used (inside the sync route, in the pool); closing it (returning the connection) is one pool hop.


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
        await run_in_threadpool(session.close)


async def get_write_session(db: Annotated[Database, Depends(get_database)]) -> AsyncIterator[Session]:
    session = db.write()
    try:
        yield session
    finally:
        await run_in_threadpool(session.close)


DatabaseDep = Annotated[Database, Depends(get_database)]
SettingsDep = Annotated[Settings, Depends(get_settings_dep)]
ArtifactsDep = Annotated[ArtifactStore, Depends(get_artifacts)]
SessionDep = Annotated[Session, Depends(get_read_session)]
WriteSessionDep = Annotated[Session, Depends(get_write_session)]


class TokenCache:
    """Token -> caller for `ttl` seconds, so most requests skip the token lookup. A revoked token
    or deactivated user is refused at most `ttl` seconds later; ttl 0 disables the cache."""

    def __init__(self, ttl: float) -> None:
        self.ttl = ttl
        self._entries: dict[str, tuple[AuthUser, float]] = {}
        self._lock = threading.Lock()

    def get(self, token: str) -> AuthUser | None:
        with self._lock:
            hit = self._entries.get(token)
        return hit[0] if hit is not None and hit[1] > time.monotonic() else None

    def put(self, token: str, user: AuthUser) -> None:
        if self.ttl <= 0:
            return
        with self._lock:
            if len(self._entries) > 10_000:
                self._entries.clear()
            self._entries[token] = (user, time.monotonic() + self.ttl)


async def get_current_user(
    request: Request,
    db: DatabaseDep,
    credentials: Annotated[HTTPAuthorizationCredentials | None, Depends(bearer)],
) -> AuthUser:
    """The caller named by a valid bearer token; 401 otherwise. Uses its own short read session."""
    if credentials is None or credentials.scheme.lower() != "bearer" or not credentials.credentials:
        raise HTTPException(status.HTTP_401_UNAUTHORIZED, "missing bearer token", {"WWW-Authenticate": "Bearer"})
    cache: TokenCache = request.app.state.token_cache
    user = cache.get(credentials.credentials)
    if user is not None:
        return user
    user = await run_in_threadpool(_lookup_token, db, credentials.credentials)
    if user is not None:
        cache.put(credentials.credentials, user)
    if user is None:
        raise HTTPException(status.HTTP_401_UNAUTHORIZED, "invalid token", {"WWW-Authenticate": "Bearer"})
    return user


CurrentUser = Annotated[AuthUser, Depends(get_current_user)]


def _lookup_token(db: Database, token: str) -> AuthUser | None:
    with db.read() as session:
        return crud.user_for_token(session, token)


async def require_admin(user: CurrentUser) -> AuthUser:
    if not user.is_admin:
        raise HTTPException(status.HTTP_403_FORBIDDEN, "admin role required")
    return user


AdminUser = Annotated[AuthUser, Depends(require_admin)]

IdPath = Annotated[int, Path(ge=1, le=MAX_ID)]
BigIdPath = Annotated[int, Path(ge=1, le=MAX_BIG_ID)]
