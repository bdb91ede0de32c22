"""Users and their tokens."""

from __future__ import annotations

from pydantic import BaseModel, Field

from app.schemas.base import (
    Role,
    UtcDateTime,
    _Public,
    _Request,
)


class UserBase(_Request):
    name: str = Field(min_length=1, max_length=64, pattern=r"^[A-Za-z0-9_.@-]+$")
    role: Role = "operator"


EXPIRES_HELP = "Days the token is valid; the service's token_expiry_days (90) when omitted."


class UserCreate(UserBase):
    expires_days: float | None = Field(default=None, gt=0, le=36500, description=EXPIRES_HELP)


class TokenCreate(_Request):
    expires_days: float | None = Field(default=None, gt=0, le=36500, description=EXPIRES_HELP)


class TokenPublic(_Public):
    id: int
    prefix: str = Field(description="The token's first characters (to tell tokens apart, and to revoke one).")
    created_at: UtcDateTime
    created_by_id: int | None
    expires_at: UtcDateTime | None
    revoked_at: UtcDateTime | None


class TokenRevoke(_Request):
    prefix: str = Field(min_length=6, max_length=64, description="Revoke the live tokens starting with this.")


class RevokeResult(BaseModel):
    revoked: int


class UserPublic(_Public):
    id: int
    name: str
    role: Role
    active: bool
    created_at: UtcDateTime


class UserWithToken(BaseModel):
    user: UserPublic
    token: str = Field(description="Shown once; only its hash is stored.")
