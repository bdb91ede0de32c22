"""Stitches (issue 5): two tracks joined by fragment links, for the operator to confirm (one
object) or reject. A confirmed stitch's fragment pairs between two accepted tracks are verified
constraints (`GET /exports/constraints`, the `train` job). Decisions carry the
stitch's version: 404 unknown stitch, 409 stale version or sequence not ready, 422 bad body."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Query

from app.api.deps import CurrentUser, IdPath, LeaseGuardDep, SessionDep, WriteSessionDep
from app.crud import stitches
from app.schemas import StitchDecision, StitchList, StitchPublic, StitchStatus

router = APIRouter(tags=["stitches"])
BIG = 2**31 - 1
DECIDE_RESPONSES: dict[int | str, dict[str, str]] = {
    404: {"description": "No such stitch."},
    409: {"description": "Stale version, its sequence is not ready, or a track is leased to another user."},
    422: {"description": "Missing or invalid version."},
}


@router.get("/stitches")
def list_stitches(
    _user: CurrentUser,
    session: SessionDep,
    sequence_id: Annotated[int | None, Query(ge=1, le=BIG)] = None,
    status: StitchStatus | None = None,
    track_id: Annotated[int | None, Query(ge=1, le=2**62)] = None,
    limit: Annotated[int, Query(ge=1, le=1000)] = 200,
    offset: Annotated[int, Query(ge=0, le=BIG)] = 0,
) -> StitchList:
    """Stitches, most fragment links first, filtered by sequence, status (`pending` = waiting
    for a decision) and track (either side)."""
    items, total = stitches.list_stitches(session, sequence_id, status, track_id, limit, offset)
    return StitchList(items=[StitchPublic.model_validate(i) for i in items], total=total, limit=limit, offset=offset)


@router.get("/stitches/{stitch_id}")
def read_stitch(stitch_id: IdPath, _user: CurrentUser, session: SessionDep) -> StitchPublic:
    """One stitch (404 when unknown)."""
    return StitchPublic.model_validate(stitches.get_stitch(session, stitch_id))


@router.post("/stitches/{stitch_id}/confirm", responses=DECIDE_RESPONSES)
def confirm_stitch(stitch_id: IdPath, body: StitchDecision, guard: LeaseGuardDep, session: WriteSessionDep) -> StitchPublic:
    """The two tracks show one object: their fragment pairs become constraints."""
    return StitchPublic.model_validate(stitches.decide_stitch(
        session, stitch_id, guard.user, "confirm", body.version, guard.override, guard.lease_seconds
    ))


@router.post("/stitches/{stitch_id}/reject", responses=DECIDE_RESPONSES)
def reject_stitch(stitch_id: IdPath, body: StitchDecision, guard: LeaseGuardDep, session: WriteSessionDep) -> StitchPublic:
    """The two tracks are different objects: their fragment pairs are never constraints."""
    return StitchPublic.model_validate(stitches.decide_stitch(
        session, stitch_id, guard.user, "reject", body.version, guard.override, guard.lease_seconds
    ))
