from __future__ import annotations

from fastapi import APIRouter, status
from sqlalchemy import select

from app import crud
from app.api.deps import AdminUser, CurrentUser, IdPath, SessionDep, WriteSessionDep
from app.models import User
from app.schemas import UserCreate, UserPublic, UserWithToken

router = APIRouter(prefix="/users", tags=["users"])


@router.get("/me")
def read_me(user: CurrentUser, session: SessionDep) -> UserPublic:
    """The caller."""
    return UserPublic.model_validate(session.get(User, user.id))


@router.get("")
def list_users(_admin: AdminUser, session: SessionDep) -> list[UserPublic]:
    """All users (admin)."""
    return [UserPublic.model_validate(u) for u in session.scalars(select(User).order_by(User.id)).all()]


@router.post("", status_code=status.HTTP_201_CREATED)
def create_user(body: UserCreate, admin: AdminUser, session: WriteSessionDep) -> UserWithToken:
    """Create a user and return their first token (shown once; admin)."""
    user, token = crud.create_user(session, body.name, body.role, created_by_id=admin.id)
    return UserWithToken(user=UserPublic.model_validate(user), token=token)


@router.post("/{user_id}/tokens", status_code=status.HTTP_201_CREATED)
def create_token(user_id: IdPath, admin: AdminUser, session: WriteSessionDep) -> UserWithToken:
    """Issue another token for a user (admin); the token row records the issuing admin."""
    token = crud.create_token(session, user_id, created_by_id=admin.id)
    return UserWithToken(user=UserPublic.model_validate(session.get(User, user_id)), token=token)
