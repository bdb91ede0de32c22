"""The viewer's change feed and progress in points (queries: `app.crud.changes`)."""

from __future__ import annotations

from datetime import datetime
from typing import Annotated

from fastapi import APIRouter, Query

from app.api.deps import CurrentUser, IdPath, SessionDep
from app.crud import changes
from app.schemas.changes import PointsProgress, SequenceChanges

router = APIRouter(tags=["frames"])


@router.get("/sequences/{sequence_id}/changes")
def sequence_changes(
    sequence_id: IdPath,
    _user: CurrentUser,
    session: SessionDep,
    since: Annotated[datetime | None, Query(description="the `cursor` of the previous answer; none: from now")] = None,
) -> SequenceChanges:
    """Tracks changed since `since` (their version, status and points) and the ETag of every frame
    they have points in; a frame's payload answers with the same ETag."""
    return changes.sequence_changes(session, sequence_id, since)


@router.get("/sequences/{sequence_id}/points-progress", tags=["exports"])
def points_progress(sequence_id: IdPath, _user: CurrentUser, session: SessionDep) -> PointsProgress:
    """The share of the sequence's points labelled, by the state of their tracks and the source of
    the class."""
    return changes.points_progress(session, sequence_id)
