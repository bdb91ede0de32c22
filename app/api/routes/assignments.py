"""Assignments (admin): the sequences each operator works on. An operator queues `finetune` and
`propose_anchors` jobs only on a sequence an admin assigned them to (app/jobs/policy.py);
holding a lease there, or having reviewed its tracks, gives no such right."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Query, Response, status

from app import crud
from app.api.deps import AdminUser, CurrentUser, IdPath, SessionDep, WriteSessionDep
from app.schemas import AssignmentCreate, AssignmentPublic

router = APIRouter(tags=["assignments"])
BIG = 2**31 - 1


@router.post("/assignments", status_code=status.HTTP_201_CREATED)
def create_assignment(body: AssignmentCreate, admin: AdminUser, session: WriteSessionDep) -> AssignmentPublic:
    """Assign a user to a sequence (admin). 404 unknown sequence or user; 409 already assigned."""
    return AssignmentPublic.model_validate(crud.create_assignment(session, body.sequence_id, body.user_id, admin.id))


@router.get("/assignments")
def list_assignments(
    user: CurrentUser,
    session: SessionDep,
    sequence_id: Annotated[int | None, Query(ge=1, le=BIG)] = None,
    user_id: Annotated[int | None, Query(ge=1, le=BIG)] = None,
) -> list[AssignmentPublic]:
    """Assignments, filtered: every one for an admin, the caller's own for anyone else."""
    if not user.is_admin:
        if user_id is not None and user_id != user.id:
            return []
        user_id = user.id
    return [AssignmentPublic.model_validate(a) for a in crud.list_assignments(session, sequence_id, user_id)]


@router.delete("/assignments/{assignment_id}", status_code=status.HTTP_204_NO_CONTENT, response_class=Response)
def delete_assignment(assignment_id: IdPath, _admin: AdminUser, session: WriteSessionDep) -> Response:
    """Remove an assignment (admin); the user's queued jobs stay queued."""
    crud.delete_assignment(session, assignment_id)
    return Response(status_code=status.HTTP_204_NO_CONTENT)
