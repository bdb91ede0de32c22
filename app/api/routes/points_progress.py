"""Progress in points: how much of a sequence's point cloud the reviews have labelled.

Tracks count unevenly (a parked bus and a one-frame bush are one track each), so the viewer's
progress bar shows points: the points of the kept frames of every track, split by the track's
state, and among the labelled ones by where the class came from (`review` or `bulk`).
"""

from __future__ import annotations

from fastapi import APIRouter
from pydantic import BaseModel, Field
from sqlalchemy import and_, func, select

from app.api.deps import CurrentUser, IdPath, SessionDep
from app.core.errors import NotFound
from app.models import Frame, Segment, Sequence, Track

router = APIRouter(tags=["exports"])


class PointsProgress(BaseModel):
    sequence_id: int
    points: int = Field(description="All points of the sequence's frames (ground included).")
    points_in_tracks: int = Field(description="Points of the kept frames of its tracks (merged-away ones excluded).")
    points_labelled: int = Field(description="Of those, points of accepted tracks with a class.")
    points_labelled_per_source: dict[str, int]
    points_accepted_unlabelled: int
    points_discarded: int
    points_pending: int


@router.get("/sequences/{sequence_id}/points-progress")
def points_progress(sequence_id: IdPath, _user: CurrentUser, session: SessionDep) -> PointsProgress:
    """The share of the sequence's points labelled, by the state of their tracks and the source of
    the class."""
    if session.get(Sequence, sequence_id) is None:
        raise NotFound(f"sequence {sequence_id} not found")
    total = session.scalar(select(func.coalesce(func.sum(Frame.n_points), 0)).where(Frame.sequence_id == sequence_id))
    kept = and_(Segment.track_id == Track.id, Segment.frame_index.between(Track.keep_start, Track.keep_end))
    rows = session.execute(
        select(Track.status, Track.label.is_not(None).label("has_label"), Track.label_source,
               func.coalesce(func.sum(Segment.n_points), 0))
        .join(Segment, kept)
        .where(Track.sequence_id == sequence_id, Track.status != "merged")
        .group_by(Track.status, Track.label.is_not(None), Track.label_source)
    ).all()
    per_source: dict[str, int] = {}
    accepted_bare = discarded = pending = 0
    for status, has_label, source, n in rows:
        n = int(n)
        if status == "accepted" and has_label:
            per_source[source or "review"] = per_source.get(source or "review", 0) + n
        elif status == "accepted":
            accepted_bare += n
        elif status == "discarded":
            discarded += n
        else:
            pending += n
    labelled = sum(per_source.values())
    return PointsProgress(
        sequence_id=sequence_id, points=int(total or 0), points_in_tracks=labelled + accepted_bare + discarded + pending,
        points_labelled=labelled, points_labelled_per_source=per_source, points_accepted_unlabelled=accepted_bare,
        points_discarded=discarded, points_pending=pending,
    )
