"""Annotated dependencies shared by the routes: sessions, settings, artifacts, the caller."""

from __future__ import annotations

from collections.abc import Iterator
from typing import Annotated

from fastapi import Depends, HTTPException, Path, Request, status
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


def get_database(request: Request) -> Database:
    return request.app.state.db


def get_settings_dep(request: Request) -> Settings:
    return request.app.state.settings


def get_artifacts(request: Request) -> ArtifactStore:
    return request.app.state.artifacts


def get_read_session(db: Annotated[Database, Depends(get_database)]) -> Iterator[Session]:
    with db.read() as session:
        yield session


def get_write_session(db: Annotated[Database, Depends(get_database)]) -> Iterator[Session]:
    with db.write() as session:
        yield session


DatabaseDep = Annotated[Database, Depends(get_database)]
SettingsDep = Annotated[Settings, Depends(get_settings_dep)]
ArtifactsDep = Annotated[ArtifactStore, Depends(get_artifacts)]
SessionDep = Annotated[Session, Depends(get_read_session)]
WriteSessionDep = Annotated[Session, Depends(get_write_session)]


def get_current_user(
    db: DatabaseDep, credentials: Annotated[HTTPAuthorizationCredentials | None, Depends(bearer)]
) -> AuthUser:
    """The caller named by a valid bearer token; 401 otherwise. Uses its own short read session."""
    if credentials is None or credentials.scheme.lower() != "bearer" or not credentials.credentials:
        raise HTTPException(status.HTTP_401_UNAUTHORIZED, "missing bearer token", {"WWW-Authenticate": "Bearer"})
    with db.read() as session:
        user = crud.user_for_token(session, credentials.credentials)
    if user is None:
        raise HTTPException(status.HTTP_401_UNAUTHORIZED, "invalid token", {"WWW-Authenticate": "Bearer"})
    return user


CurrentUser = Annotated[AuthUser, Depends(get_current_user)]


def require_admin(user: CurrentUser) -> AuthUser:
    if not user.is_admin:
        raise HTTPException(status.HTTP_403_FORBIDDEN, "admin role required")
    return user


AdminUser = Annotated[AuthUser, Depends(require_admin)]

IdPath = Annotated[int, Path(ge=1, le=MAX_ID)]
BigIdPath = Annotated[int, Path(ge=1, le=MAX_BIG_ID)]
