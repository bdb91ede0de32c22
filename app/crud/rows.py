"""What every resource's crud module shares: a row by id, or 404."""

from __future__ import annotations

from typing import TypeVar

from sqlalchemy.orm import Session

from app.core.errors import NotFound

T = TypeVar("T")


def get_or_404(session: Session, model: type[T], row_id: int, what: str) -> T:
    """The `model` row `row_id`; NotFound ("<what> <id> not found") when there is none."""
    row = session.get(model, row_id)
    if row is None:
        raise NotFound(f"{what} {row_id} not found")
    return row
