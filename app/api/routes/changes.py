"""What changed in a sequence since a moment: the feed that keeps open viewer tabs true.

A viewer polls `GET /sequences/{id}/changes?since=<cursor>` and gets every track whose row
changed since then (any action, split, merge, undo, bulk accept: each bumps `updated_at` and
`version`) and the ETag of every frame those tracks have segments in (a split, a merge or an undo
rewrites only frames of the tracks it changes). The cursor it gets back lies `OVERLAP` before
the query, so a change committed just after the query by a transaction that stamped it just
before is reported by the next poll; the viewer compares versions and ETags, so a repeat is
harmless. A track a split created and its undo removed is no longer listed: its frames are
those of the track it was cut from, which is.
"""

from __future__ import annotations

from datetime import datetime, timedelta
from typing import Annotated

from fastapi import APIRouter, Query
from pydantic import BaseModel
from sqlalchemy import select

from app.api.deps import CurrentUser, IdPath, SessionDep
from app.core.errors import NotFound
from app.models import Frame, Segment, Sequence, Track, utcnow
from app.versions import frame_etag

router = APIRouter(tags=["frames"])

OVERLAP = timedelta(seconds=5)
MAX_TRACKS = 5000


class TrackVersion(BaseModel):
    id: int
    version: int
    status: str
    n_points: int


class FrameVersion(BaseModel):
    id: int
    index: int
    etag: str


class SequenceChanges(BaseModel):
    cursor: datetime  # pass back as `since`
    tracks: list[TrackVersion]
    frames: list[FrameVersion]
    truncated: bool  # more than MAX_TRACKS tracks changed: drop every cache of the sequence


@router.get("/sequences/{sequence_id}/changes")
def sequence_changes(
    sequence_id: IdPath,
    _user: CurrentUser,
    session: SessionDep,
    since: Annotated[datetime | None, Query(description="the `cursor` of the previous answer; none: from now")] = None,
) -> SequenceChanges:
    """Tracks changed since `since` (their version, status and points) and the ETag of every frame
    they have points in; a frame's payload answers with the same ETag."""
    if session.get(Sequence, sequence_id) is None:
        raise NotFound(f"sequence {sequence_id} not found")
    now = utcnow()
    cursor = now - OVERLAP
    if since is None:
        return SequenceChanges(cursor=cursor, tracks=[], frames=[], truncated=False)
    since = since.replace(tzinfo=None)  # the columns hold naive UTC
    rows = session.execute(
        select(Track.id, Track.version, Track.status, Track.n_points)
        .where(Track.sequence_id == sequence_id, Track.updated_at >= since)
        .order_by(Track.id).limit(MAX_TRACKS + 1)
    ).all()
    truncated = len(rows) > MAX_TRACKS
    tracks = [TrackVersion(id=r.id, version=r.version, status=r.status, n_points=r.n_points) for r in rows[:MAX_TRACKS]]
    frames: list[FrameVersion] = []
    if tracks and not truncated:
        frame_rows = session.execute(
            select(Frame.id, Frame.index, Frame.artifact).where(
                Frame.id.in_(select(Segment.frame_id).where(Segment.track_id.in_([t.id for t in tracks])))
            ).order_by(Frame.index)
        ).all()
        frames = [FrameVersion(id=f.id, index=f.index, etag=frame_etag(f.artifact)) for f in frame_rows]
    return SequenceChanges(cursor=cursor, tracks=tracks, frames=frames, truncated=truncated)
