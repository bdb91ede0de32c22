from __future__ import annotations

import inspect
from typing import Annotated, Literal

from fastapi import APIRouter, Query, Response
from pydantic import Field

from app import crud
from app.api.deps import (
    MAX_BIG_ID,
    ArtifactsDep,
    BigIdPath,
    CurrentUser,
    LeaseGuardDep,
    SessionDep,
    WriteSessionDep,
)
from app.core.errors import NotFound
from app.crud.frames import segment_sample_ref
from app.schemas import (
    ActionBase,
    ClassName,
    EventPublic,
    SegmentPublic,
    TrackDetail,
    TrackList,
    TrackPublic,
    TrackStatus,
)

router = APIRouter(tags=["tracks"])

SortKey = Literal[tuple(k for key in crud.TRACK_SORTS for k in (key, f"-{key}"))]  # type: ignore[valid-type]
BIG = 2**31 - 1


@router.get("/tracks")
def list_tracks(
    _user: CurrentUser,
    session: SessionDep,
    sequence_id: Annotated[int | None, Query(ge=1, le=BIG)] = None,
    status: TrackStatus | None = None,
    label: ClassName | None = None,
    unlabelled: bool | None = None,
    min_length: Annotated[int | None, Query(ge=0, le=BIG)] = None,
    max_length: Annotated[int | None, Query(ge=0, le=BIG)] = None,
    predicted_class: ClassName | None = None,
    min_confidence: Annotated[float | None, Query(ge=0.0, le=1.0)] = None,
    max_confidence: Annotated[float | None, Query(ge=0.0, le=1.0)] = None,
    sort: SortKey = "id",
    limit: Annotated[int, Query(ge=1, le=500)] = 50,
    offset: Annotated[int, Query(ge=0, le=BIG)] = 0,
    ids: Annotated[
        list[Annotated[int, Field(ge=1, le=MAX_BIG_ID)]] | None,
        Query(max_length=500, description="Only these track ids (e.g. the tracks seen in one frame)."),
    ] = None,
) -> TrackList:
    """Tracks filtered by id, status, class, length (frames), predicted class and confidence; sorted
    by `sort` (`-` = descending) and paginated."""
    crud.check_class_filter(session, "label", label, sequence_id)
    crud.check_class_filter(session, "predicted_class", predicted_class, sequence_id)
    flt = crud.TrackFilter(
        sequence_id, status, label, unlabelled, min_length, max_length, predicted_class, min_confidence, max_confidence,
        ids=None if ids is None else tuple(sorted(set(ids))),
    )
    rows, total = crud.list_tracks(session, flt, sort, limit, offset)
    return TrackList(items=[TrackPublic.model_validate(t) for t in rows], total=total, limit=limit, offset=offset)


@router.get("/tracks/{track_id}")
def read_track(track_id: BigIdPath, _user: CurrentUser, session: SessionDep) -> TrackDetail:
    """A track with its segments per frame; each sample is served as PNG at `sample_url`."""
    track = crud.get_track(session, track_id)
    segs = [
        SegmentPublic(
            id=s.id,
            frame_id=s.frame_id,
            frame_index=s.frame_index,
            local_id=s.local_id,
            n_points=s.n_points,
            centroid=(s.cx, s.cy, s.cz),
            centroid_world=(s.wx, s.wy, s.wz),
            range=s.range,
            valid=s.valid,
            link_score=s.link_score,
            in_kept_range=track.keep_start <= s.frame_index <= track.keep_end,
            sample_url=None if s.sample_index is None else f"/api/v1/segments/{s.id}/sample.png",
        )
        for s in crud.track_segments(session, track_id)
    ]
    return TrackDetail(**TrackPublic.model_validate(track).model_dump(), segments=segs)


@router.get("/tracks/{track_id}/events")
def track_events(track_id: BigIdPath, _user: CurrentUser, session: SessionDep) -> list[EventPublic]:
    """The track's append-only event log (who, when, action, before, after)."""
    crud.get_track(session, track_id)
    return [EventPublic.model_validate(e) for e in crud.track_events(session, track_id)]


def _act(session: WriteSessionDep, track_id: int, guard: LeaseGuardDep, action: str, version: int, **kw: object) -> TrackPublic:
    track = crud.apply_action(
        session, track_id, guard.user, action, version,
        override_lease=guard.override, lease_seconds=guard.lease_seconds, **kw,  # type: ignore[arg-type]
    )
    return TrackPublic.model_validate(track)


def _action_route(action: crud.ReviewAction) -> None:
    """POST /tracks/{track_id}/<action> with the action's body (`crud.REVIEW_ACTIONS`)."""

    def endpoint(track_id: BigIdPath, body: ActionBase, guard: LeaseGuardDep, session: WriteSessionDep) -> TrackPublic:
        return _act(session, track_id, guard, action.name, body.version, **body.model_dump(exclude={"version"}))

    sig = inspect.signature(endpoint)
    endpoint.__signature__ = sig.replace(  # type: ignore[attr-defined]
        parameters=[p.replace(annotation=action.body) if p.name == "body" else p for p in sig.parameters.values()])
    endpoint.__name__ = endpoint.__qualname__ = f"{action.name}_track"
    endpoint.__doc__ = action.route_doc
    router.post(f"/tracks/{{track_id}}/{action.name}")(endpoint)


for _action in crud.REVIEW_ACTIONS.values():
    if _action.route_doc is not None:
        _action_route(_action)


@router.get(
    "/segments/{segment_id}/sample.png",
    response_class=Response,
    responses={200: {"content": {"image/png": {}}, "description": "the sample"}},
)
def segment_sample(
    segment_id: BigIdPath,
    _user: CurrentUser,
    session: SessionDep,
    artifacts: ArtifactsDep,
    channel: Annotated[int | None, Query(ge=0, le=15)] = None,
) -> Response:
    """A segment's sample as PNG: its channels side by side in grey (height, range, intensity,
    foreground mask), or only `channel`."""
    import cv2
    import numpy as np

    rel, sample_index = segment_sample_ref(session, segment_id)
    samples = artifacts.read_arrays(rel, ("samples",))["samples"]
    sample = samples[sample_index]  # (C, S, S)
    if channel is not None:
        if channel >= len(sample):
            raise NotFound(f"sample has {len(sample)} channels")
        image = sample[channel]
    else:
        image = np.concatenate(list(sample), axis=1)  # (S, C*S)
    ok, png = cv2.imencode(".png", np.ascontiguousarray(image))
    assert ok
    return Response(content=png.tobytes(), media_type="image/png")
