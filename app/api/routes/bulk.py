"""Bulk accept (the model in the review loop): accept every pending track of a sequence that the
model predicts as one class with at least a confidence, in one action; preview it first; undo it
in one action. Each track's own event names the bulk, so a single track undoes like any action."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Query

from app import crud
from app.api.deps import CurrentUser, IdPath, SessionDep, WriteSessionDep
from app.schemas import BulkAcceptAction, BulkActionPublic, BulkPreview, ClassName

router = APIRouter(tags=["review"])


def _sequence(session: SessionDep | WriteSessionDep, sequence_id: int) -> None:
    crud.get_sequence(session, sequence_id)


@router.get("/sequences/{sequence_id}/bulk-accept/preview")
def preview(
    sequence_id: IdPath,
    user: CurrentUser,
    session: SessionDep,
    class_name: ClassName,
    min_confidence: Annotated[float, Query(ge=0.0, le=1.0)],
) -> BulkPreview:
    """What a bulk accept of `class_name` at `min_confidence` would label now: tracks, points,
    confidences and the largest tracks (to look at before accepting)."""
    _sequence(session, sequence_id)
    return BulkPreview(**crud.bulk_preview(session, sequence_id, class_name, min_confidence, user))


@router.post("/sequences/{sequence_id}/bulk-accept")
def accept(sequence_id: IdPath, body: BulkAcceptAction, user: CurrentUser, session: WriteSessionDep) -> BulkActionPublic:
    """Accept every pending track predicted as `class_name` with confidence >= `min_confidence`
    (tracks another operator has leased are left out). 409 when none matches, or when
    `expected_tracks` differs from the count now."""
    _sequence(session, sequence_id)
    bulk = crud.bulk_accept(session, sequence_id, user, body.class_name, body.min_confidence,
                            body.expected_tracks)
    return BulkActionPublic.model_validate(bulk)


@router.get("/sequences/{sequence_id}/bulk-actions")
def list_bulk(sequence_id: IdPath, _user: CurrentUser, session: SessionDep) -> list[BulkActionPublic]:
    """The sequence's bulk accepts, oldest first."""
    _sequence(session, sequence_id)
    return [BulkActionPublic.model_validate(b) for b in crud.list_bulk_actions(session, sequence_id)]


@router.post("/bulk-actions/{bulk_id}/undo")
def undo(bulk_id: IdPath, user: CurrentUser, session: WriteSessionDep) -> BulkActionPublic:
    """Undo a bulk accept: its tracks that nobody changed since go back to pending. 409 when it
    was undone already."""
    return BulkActionPublic.model_validate(crud.undo_bulk(session, bulk_id, user))
