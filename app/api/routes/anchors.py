"""Anchor proposals (issue 7): list them, answer them (confirm, correct, reject), see who did.

Proposals come from `propose_anchors` jobs (POST /jobs); a `finetune` job trains on the
confirmed ones. Answers: 404 when the proposal no longer exists (a newer proposal run replaced
it, or the sequence was re-ingested), 409 when it was already answered or its track was
discarded meanwhile, 422 for an unknown class.
"""

from __future__ import annotations

from typing import Annotated, Literal

from fastapi import APIRouter, Query

from app import crud
from app.api.deps import CurrentUser, IdPath, SessionDep, WriteSessionDep
from app.crud import anchors
from app.schemas import (
    AnchorCorrect,
    AnchorEventPublic,
    AnchorLevel,
    AnchorList,
    AnchorPublic,
    AnchorStatus,
    AnchorSummary,
    ClassName,
)

router = APIRouter(tags=["anchors"])

Strategy = Literal["confident", "entropy", "diverse", "track", "track_diverse"]
BIG = 2**31 - 1
ANSWER_RESPONSES: dict[int | str, dict[str, str]] = {
    404: {"description": "The proposal no longer exists (replaced by a newer proposal run, or re-ingested)."},
    409: {"description": "Already answered, its track was discarded, or its sequence is not ready."},
    422: {"description": "Unknown class."},
}


@router.get("/anchors")
def list_anchors(
    _user: CurrentUser,
    session: SessionDep,
    sequence_id: Annotated[int | None, Query(ge=1, le=BIG)] = None,
    status: AnchorStatus | None = None,
    level: AnchorLevel | None = None,
    strategy: Strategy | None = None,
    proposed_class: ClassName | None = None,
    track_id: Annotated[int | None, Query(ge=1, le=2**62)] = None,
    limit: Annotated[int, Query(ge=1, le=1000)] = 200,
    offset: Annotated[int, Query(ge=0, le=BIG)] = 0,
) -> AnchorList:
    """Anchor proposals, class by class and best first within a class, filtered by sequence,
    status (`proposed` = waiting for an answer), level, strategy, proposed class or track."""
    crud.check_class_filter(session, "proposed_class", proposed_class, sequence_id)
    flt = anchors.AnchorFilter(sequence_id, status, level, strategy, proposed_class, track_id)
    items, total = anchors.list_anchors(session, flt, limit, offset)
    return AnchorList(items=[AnchorPublic(**i) for i in items], total=total, limit=limit, offset=offset)


@router.get("/anchors/summary")
def anchor_summary(
    _user: CurrentUser,
    session: SessionDep,
    sequence_id: Annotated[int | None, Query(ge=1, le=BIG)] = None,
) -> AnchorSummary:
    """Proposals by status, and per class: waiting, confirmed (by answer class), corrected, rejected."""
    return AnchorSummary.model_validate(anchors.anchor_summary(session, sequence_id))


@router.get("/anchors/{anchor_id}")
def read_anchor(anchor_id: IdPath, _user: CurrentUser, session: SessionDep) -> AnchorPublic:
    """One proposal (404 when it no longer exists)."""
    return AnchorPublic(**anchors.get_anchor(session, anchor_id))


@router.get("/anchors/{anchor_id}/events")
def anchor_events(anchor_id: IdPath, _user: CurrentUser, session: SessionDep) -> list[AnchorEventPublic]:
    """Who answered the proposal, when, and how."""
    return [AnchorEventPublic.model_validate(e) for e in anchors.anchor_events(session, anchor_id)]


@router.post("/anchors/{anchor_id}/confirm", responses=ANSWER_RESPONSES)
def confirm_anchor(anchor_id: IdPath, user: CurrentUser, session: WriteSessionDep) -> AnchorPublic:
    """Confirm the proposed class. A track-level proposal labels its whole track (as the track
    `label` action does). Already answered -> 409; gone -> 404."""
    return AnchorPublic(**anchors.answer_anchor(session, anchor_id, user, "confirm"))


@router.post("/anchors/{anchor_id}/correct", responses=ANSWER_RESPONSES)
def correct_anchor(anchor_id: IdPath, body: AnchorCorrect, user: CurrentUser, session: WriteSessionDep) -> AnchorPublic:
    """Answer with another class (`label`); unknown class -> 422. A track-level proposal labels its
    whole track with it. Already answered -> 409; gone -> 404."""
    return AnchorPublic(**anchors.answer_anchor(session, anchor_id, user, "correct", body.label))


@router.post("/anchors/{anchor_id}/reject", responses=ANSWER_RESPONSES)
def reject_anchor(anchor_id: IdPath, user: CurrentUser, session: WriteSessionDep) -> AnchorPublic:
    """Reject the proposal (not a usable anchor: a wrong segment or association). Already
    answered -> 409; gone -> 404."""
    return AnchorPublic(**anchors.answer_anchor(session, anchor_id, user, "reject"))

