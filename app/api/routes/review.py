from __future__ import annotations

from typing import Annotated, Literal

from fastapi import APIRouter, Query, Response, status
from pydantic import Field

from app import crud
from app.api.deps import MAX_BIG_ID, BigIdPath, CurrentUser, SettingsDep, WriteSessionDep
from app.schemas import TrackPublic

router = APIRouter(prefix="/review", tags=["review"])


@router.post(
    "/next", response_model=TrackPublic, responses={204: {"description": "no unreviewed track is free"}}
)
def next_track(
    user: CurrentUser,
    session: WriteSessionDep,
    settings: SettingsDep,
    sequence_id: Annotated[int | None, Query(ge=1, le=2**31 - 1)] = None,
    exclude: Annotated[
        list[Annotated[int, Field(ge=1, le=MAX_BIG_ID)]] | None,
        Query(max_length=1000, description="Track ids to pass over (held by the caller's other viewer tabs, or skipped)."),
    ] = None,
    order: Annotated[Literal["priority", "size"], Query(description=(
        "priority: the points a review is expected to correct first (the model's uncertain large tracks); "
        "size: the largest tracks first."))] = "priority",
) -> TrackPublic | Response:
    """Lease the next unreviewed track to the caller for `review_lease_seconds`.

    Two operators never get the same track while its lease runs; the caller's own live lease is
    returned again (unless it is in `exclude`); an expired lease frees the track. 204 when nothing is left.
    """
    track = crud.lease_next_track(
        session, user, settings.review_lease_seconds, sequence_id, tuple(sorted(set(exclude or ()))), order
    )
    if track is None:
        return Response(status_code=status.HTTP_204_NO_CONTENT)
    return TrackPublic.model_validate(track)


@router.post("/{track_id}/lease", response_model=TrackPublic,
             responses={404: {"description": "unknown track"},
                        409: {"description": "another operator's lease on the track is running"}})
def lease(track_id: BigIdPath, user: CurrentUser, session: WriteSessionDep, settings: SettingsDep) -> TrackPublic:
    """Lease a chosen pending track to the caller for `review_lease_seconds` (a track opened out
    of queue order), so that `next` hands it to no one else; a reviewed track is returned as it
    is. 409 while another operator holds it."""
    return TrackPublic.model_validate(crud.lease_track(session, track_id, user, settings.review_lease_seconds))


@router.post("/{track_id}/release", status_code=status.HTTP_204_NO_CONTENT)
def release(track_id: BigIdPath, user: CurrentUser, session: WriteSessionDep) -> None:
    """Give back the caller's lease on a track."""
    crud.release_lease(session, track_id, user)
