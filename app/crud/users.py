"""Users and their API tokens."""

from __future__ import annotations

from dataclasses import dataclass
from datetime import timedelta
from typing import Any

from sqlalchemy import Connection, bindparam, or_, select, update
from sqlalchemy.orm import Session

from app.core.errors import Conflict, Invalid, NotFound
from app.core.security import hash_token, new_token, token_display_prefix
from app.crud.rows import get_or_404
from app.models import ROLES, ApiToken, User, utcnow


@dataclass(frozen=True)
class AuthUser:
    """The caller, detached from any session."""

    id: int
    name: str
    role: str

    @property
    def is_admin(self) -> bool:
        return self.role == "admin"


def create_user(
    session: Session, name: str, role: str, created_by_id: int | None = None, expires_days: float = 90.0
) -> tuple[User, str]:
    """Create a user and a first token valid for `expires_days`; returns the user and the token
    (shown once). Commits."""
    if role not in ROLES:
        raise Invalid(f"unknown role {role!r}; valid: {', '.join(ROLES)}")
    if session.scalar(select(User.id).where(User.name == name)) is not None:
        raise Conflict(f"user {name!r} exists")
    user = User(name=name, role=role, created_by_id=created_by_id, active=True)
    session.add(user)
    session.flush()
    token = _add_token(session, user.id, created_by_id, expires_days)
    session.commit()
    return user, token


def create_token(session: Session, user_id: int, created_by_id: int | None = None, expires_days: float = 90.0) -> str:
    """A new token for an existing user, valid for `expires_days`, issued by `created_by_id`
    (None = the CLI). Commits."""
    if session.get(User, user_id) is None:
        raise NotFound(f"user {user_id} not found")
    token = _add_token(session, user_id, created_by_id, expires_days)
    session.commit()
    return token


def _add_token(session: Session, user_id: int, created_by_id: int | None, expires_days: float) -> str:
    if not 0 < expires_days <= 36500:
        raise Invalid(f"expires_days must be in (0, 36500], got {expires_days:g}")
    token = new_token()
    now = utcnow()
    session.add(ApiToken(user_id=user_id, token_hash=hash_token(token), prefix=token_display_prefix(token),
                         created_by_id=created_by_id, created_at=now, expires_at=now + timedelta(days=expires_days)))
    return token


# Built once: every request looks its token up, and building this statement each time cost more
# than running it.
_TOKEN_OWNER = (
    select(User.id, User.name, User.role)
    .join(ApiToken, ApiToken.user_id == User.id)
    .where(
        ApiToken.token_hash == bindparam("token_hash"),
        ApiToken.revoked_at.is_(None),
        or_(ApiToken.expires_at.is_(None), ApiToken.expires_at > bindparam("now")),
        User.active.is_(True),
    )
)


def user_for_token(conn: Connection | Session, token: str) -> AuthUser | None:
    """The active user owning an unrevoked, unexpired `token`, or None."""
    row = conn.execute(_TOKEN_OWNER, {"token_hash": hash_token(token), "now": utcnow()}).first()
    return None if row is None else AuthUser(id=row.id, name=row.name, role=row.role)


def user_id_by_name(session: Session, name: str) -> int | None:
    """The id of the user called `name`, None when there is none."""
    return session.scalar(select(User.id).where(User.name == name))


def user_role(session: Session, user_id: int | None) -> str | None:
    """The user's role, None for no user (a job the service queued itself) or an unknown id."""
    return session.scalar(select(User.role).where(User.id == user_id))


def get_user_by_name(session: Session, name: str) -> User:
    user = session.scalar(select(User).where(User.name == name))
    if user is None:
        raise NotFound(f"user {name!r} not found")
    return user


def revoke_tokens(session: Session, *, user_id: int | None = None, prefix: str | None = None) -> int:
    """Revoke every live token of a user, or those whose display prefix starts with `prefix`
    (at least 6 characters, so that one typo cannot revoke everyone's). Returns how many; Commits."""
    where: list[Any] = [ApiToken.revoked_at.is_(None)]
    if user_id is not None:
        where.append(ApiToken.user_id == user_id)
    if prefix is not None:
        if len(prefix) < 6:
            raise Invalid(f"token prefix {prefix!r} is too short: give at least 6 characters (e.g. tl_AbC)")
        where.append(ApiToken.prefix.startswith(prefix[: len(token_display_prefix(prefix))], autoescape=True))
    if user_id is None and prefix is None:
        raise Invalid("name a user or a token prefix")
    n = session.execute(update(ApiToken).where(*where).values(revoked_at=utcnow())).rowcount
    if prefix is not None and n == 0:
        raise NotFound(f"no live token starts with {prefix!r}")
    session.commit()
    return int(n)


def set_user_active(session: Session, user_id: int, active: bool) -> User:
    """Disable (refused from the next request on; tokens kept) or re-enable a user. Commits."""
    user = session.get(User, user_id)
    if user is None:
        raise NotFound(f"user {user_id} not found")
    user.active = active
    session.commit()
    return user


def list_tokens(session: Session, user_id: int) -> list[ApiToken]:
    if session.get(User, user_id) is None:
        raise NotFound(f"user {user_id} not found")
    return list(session.scalars(select(ApiToken).where(ApiToken.user_id == user_id).order_by(ApiToken.id)).all())


def list_users(session: Session) -> list[User]:
    return list(session.scalars(select(User).order_by(User.id)).all())


def get_user(session: Session, user_id: int) -> User:
    return get_or_404(session, User, user_id, "user")
