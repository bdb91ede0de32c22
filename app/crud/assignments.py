"""Assignments: which users an admin put on which sequences (what operators may queue jobs on)."""

from __future__ import annotations

from sqlalchemy import select
from sqlalchemy.orm import Session

from app.core.errors import Conflict, NotFound
from app.models import Assignment, Sequence, User


def create_assignment(session: Session, sequence_id: int, user_id: int, created_by_id: int) -> Assignment:
    """Assign a user to a sequence. NotFound for either unknown; Conflict when already assigned. Commits."""
    if session.get(Sequence, sequence_id) is None:
        raise NotFound(f"sequence {sequence_id} not found")
    if session.get(User, user_id) is None:
        raise NotFound(f"user {user_id} not found")
    existing = session.scalar(select(Assignment.id).where(Assignment.sequence_id == sequence_id, Assignment.user_id == user_id))
    if existing is not None:
        raise Conflict(f"user {user_id} is already assigned to sequence {sequence_id} (assignment {existing})")
    row = Assignment(sequence_id=sequence_id, user_id=user_id, created_by_id=created_by_id)
    session.add(row)
    session.commit()
    return row


def list_assignments(session: Session, sequence_id: int | None, user_id: int | None) -> list[Assignment]:
    q = select(Assignment).order_by(Assignment.id)
    if sequence_id is not None:
        q = q.where(Assignment.sequence_id == sequence_id)
    if user_id is not None:
        q = q.where(Assignment.user_id == user_id)
    return list(session.scalars(q).all())


def delete_assignment(session: Session, assignment_id: int) -> None:
    """Remove an assignment (NotFound when there is none). Commits."""
    row = session.get(Assignment, assignment_id)
    if row is None:
        raise NotFound(f"assignment {assignment_id} not found")
    session.delete(row)
    session.commit()


def is_assigned(session: Session, user_id: int, sequence_id: int) -> bool:
    """True when an admin assigned the user to the sequence."""
    return session.scalar(
        select(Assignment.id).where(Assignment.user_id == user_id, Assignment.sequence_id == sequence_id).limit(1)
    ) is not None
