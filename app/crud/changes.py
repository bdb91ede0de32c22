"""What changed in a sequence since a moment, and how many of its points the reviews labelled:
the queries behind the viewer's change feed and its progress bar.

A viewer polls `GET /sequences/{id}/changes?since=<cursor>` and gets every track whose row
changed since then (any action, split, merge, undo, bulk accept: each bumps `updated_at` and
`version`) and the ETag of every frame those tracks have segments in (a split, a merge or an undo
rewrites only frames of the tracks it changes). The cursor it gets back lies `OVERLAP` before
the query, so a change committed just after the query by a transaction that stamped it just
before is reported by the next poll; the viewer compares versions and ETags, so a repeat is
harmless. A track a split created and its undo removed is no longer listed: its frames are
those of the track it was cut from, which is. Every answer also lists the ids of the
sequence's live ground regions (a drawn or undone region changes them, whenever it happened): a
viewer compares them with the regions it shows, not with the previous answer, since it may have
read a region itself between two polls that then drew and undid it.

Tracks count unevenly (a parked bus and a one-frame bush are one track each), so progress is in
points: the points of the kept frames of every track, split by the track's state, and among the
labelled ones by where the class came from (`review` or `bulk`).
"""

from __future__ import annotations

from datetime import UTC, datetime, timedelta

from sqlalchemy import and_, func, select
from sqlalchemy.orm import Session

from app.artifacts import frame_etag
from app.core.errors import NotFound
from app.crud.ground_regions import region_ids
from app.models import Frame, Segment, Sequence, Track, utcnow
from app.schemas.changes import FrameVersion, PointsProgress, SequenceChanges, TrackVersion

OVERLAP = timedelta(seconds=5)
MAX_TRACKS = 5000


def _require_sequence(session: Session, sequence_id: int) -> None:
    if session.get(Sequence, sequence_id) is None:
        raise NotFound(f"sequence {sequence_id} not found")


def sequence_changes(session: Session, sequence_id: int, since: datetime | None) -> SequenceChanges:
    """Tracks changed since `since` (version, status, points) and the ETag of every frame they have
    points in; `since=None` starts a feed (a cursor, nothing changed)."""
    _require_sequence(session, sequence_id)
    cursor = utcnow() - OVERLAP
    live_regions = region_ids(session, sequence_id)
    if since is None:
        return SequenceChanges(cursor=cursor, tracks=[], frames=[], truncated=False, region_ids=live_regions)
    if since.tzinfo is not None:  # the cursor says UTC; the columns hold naive UTC
        since = since.astimezone(UTC).replace(tzinfo=None)
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
    return SequenceChanges(cursor=cursor, tracks=tracks, frames=frames, truncated=truncated, region_ids=live_regions)


def points_progress(session: Session, sequence_id: int) -> PointsProgress:
    """The sequence's points by the state of their tracks and the source of the class."""
    _require_sequence(session, sequence_id)
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
