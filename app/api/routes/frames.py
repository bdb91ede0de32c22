from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Header, Query, Response

from app.api.deps import ArtifactsDep, CurrentUser, IdPath, SessionDep
from app.artifacts import frame_etag
from app.crud import frames
from app.schemas import FrameList, FramePublic

router = APIRouter(tags=["frames"])

NPZ_MEDIA_TYPE = "application/x-npz"


@router.get("/sequences/{sequence_id}/frames")
def list_frames(
    sequence_id: IdPath,
    _user: CurrentUser,
    session: SessionDep,
    limit: Annotated[int, Query(ge=1, le=10_000)] = 1000,
    offset: Annotated[int, Query(ge=0, le=2**31)] = 0,
) -> FrameList:
    """Frames of a sequence in order (only frames whose ingest batch committed)."""
    rows, total = frames.list_frames(session, sequence_id, limit, offset)
    return FrameList(items=[FramePublic.model_validate(f) for f in rows], total=total)


@router.get("/frames/{frame_id}")
def read_frame(frame_id: IdPath, _user: CurrentUser, session: SessionDep) -> FramePublic:
    """One frame's metadata."""
    return FramePublic.model_validate(frames.get_frame(session, frame_id))


@router.get(
    "/frames/{frame_id}/payload",
    response_class=Response,
    responses={200: {"content": {NPZ_MEDIA_TYPE: {}}, "description": "uncompressed .npz"}},
)
def frame_payload_route(
    frame_id: IdPath, _user: CurrentUser, session: SessionDep, artifacts: ArtifactsDep,
    if_none_match: Annotated[str | None, Header()] = None,
) -> Response:
    """The viewer payload of a frame: an uncompressed `.npz` with `points` (N,3) float32 (lidar
    frame), `intensity` (N,) float32, `segment` (N,) int32 (-1 = ground/none), `track` (N,)
    int32 (database track id, 0 = none; int64 once ids pass 2**31) and `ground` (N,) bool (the
    ground estimate: the points a ground region labels).
    Load with `numpy.load(io.BytesIO(body))`. The `ETag` changes whenever a split, merge or undo
    rewrites the frame (`GET /sequences/{id}/changes` lists the new one); `If-None-Match` with the
    current one answers 304 without a body."""
    rel = frames.frame_artifact(session, frame_id)
    session.close()  # release the connection before the file work
    etag = frame_etag(rel)
    headers = {"Cache-Control": "private, no-cache", "ETag": etag}  # revalidate: a repair changes the frame
    if if_none_match is not None and etag in (t.strip() for t in if_none_match.split(",")):
        return Response(status_code=304, headers=headers)
    body = artifacts.payload(rel)
    return Response(content=body, media_type=NPZ_MEDIA_TYPE, headers=headers)
