"""Users and tokens. Any caller reads themselves; the rest is admin: create users, issue tokens
(expiring after `expires_days`, default `token_expiry_days`), revoke them (all of a user's, or by
prefix), disable or re-enable a user. A revoked or expired token, or a disabled user's, is refused
from the next request on."""

from __future__ import annotations

from fastapi import APIRouter, status

from app import crud
from app.api.deps import AdminUser, CurrentUser, IdPath, SessionDep, SettingsDep, WriteSessionDep
from app.schemas import (
    RevokeResult,
    TokenCreate,
    TokenPublic,
    TokenRevoke,
    UserCreate,
    UserPublic,
    UserWithToken,
)

router = APIRouter(tags=["users"])


@router.get("/users/me")
def read_me(user: CurrentUser, session: SessionDep) -> UserPublic:
    """The caller."""
    return UserPublic.model_validate(crud.get_user(session, user.id))


@router.get("/users")
def list_users(_admin: AdminUser, session: SessionDep) -> list[UserPublic]:
    """All users (admin)."""
    return [UserPublic.model_validate(u) for u in crud.list_users(session)]


@router.post("/users", status_code=status.HTTP_201_CREATED)
def create_user(body: UserCreate, admin: AdminUser, session: WriteSessionDep, settings: SettingsDep) -> UserWithToken:
    """Create a user and return their first token (shown once; admin)."""
    days = body.expires_days or settings.token_expiry_days
    user, token = crud.create_user(session, body.name, body.role, created_by_id=admin.id, expires_days=days)
    return UserWithToken(user=UserPublic.model_validate(user), token=token)


@router.post("/users/{user_id}/tokens", status_code=status.HTTP_201_CREATED)
def create_token(
    user_id: IdPath, admin: AdminUser, session: WriteSessionDep, settings: SettingsDep, body: TokenCreate | None = None
) -> UserWithToken:
    """Issue another token for a user (admin); the token row records the issuing admin."""
    days = (body.expires_days if body else None) or settings.token_expiry_days
    token = crud.create_token(session, user_id, created_by_id=admin.id, expires_days=days)
    return UserWithToken(user=UserPublic.model_validate(crud.get_user(session, user_id)), token=token)


@router.get("/users/{user_id}/tokens")
def list_tokens(user_id: IdPath, _admin: AdminUser, session: SessionDep) -> list[TokenPublic]:
    """A user's tokens: prefix, issuer, expiry, revocation (admin; the tokens themselves are never stored)."""
    return [TokenPublic.model_validate(t) for t in crud.list_tokens(session, user_id)]


@router.post("/users/{user_id}/revoke")
def revoke_user_tokens(user_id: IdPath, _admin: AdminUser, session: WriteSessionDep) -> RevokeResult:
    """Revoke every live token of a user (admin)."""
    crud.list_tokens(session, user_id)  # 404 for an unknown user
    return RevokeResult(revoked=crud.revoke_tokens(session, user_id=user_id))


@router.post("/tokens/revoke")
def revoke_tokens_by_prefix(body: TokenRevoke, _admin: AdminUser, session: WriteSessionDep) -> RevokeResult:
    """Revoke the live tokens whose prefix starts with `prefix` (admin; 404 when none does)."""
    return RevokeResult(revoked=crud.revoke_tokens(session, prefix=body.prefix))


@router.post("/users/{user_id}/disable")
def disable_user(user_id: IdPath, _admin: AdminUser, session: WriteSessionDep) -> UserPublic:
    """Deactivate a user: every token of theirs is refused from the next request on (admin)."""
    return UserPublic.model_validate(crud.set_user_active(session, user_id, False))


@router.post("/users/{user_id}/enable")
def enable_user(user_id: IdPath, _admin: AdminUser, session: WriteSessionDep) -> UserPublic:
    """Reactivate a disabled user (their unrevoked, unexpired tokens work again; admin)."""
    return UserPublic.model_validate(crud.set_user_active(session, user_id, True))
