"""Listing and reading tracks."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from sqlalchemy import func, select, update
from sqlalchemy.orm import Session

from app.crud.rows import get_or_404
from app.models import AnnotationEvent, Segment, Track

TRACK_SORTS = {
    "id": Track.id,
    "length": Track.length,
    "n_samples": Track.n_samples,
    "n_points": Track.n_points,
    "mean_range": Track.mean_range,
    "confidence": Track.predicted_confidence,
    "updated_at": Track.updated_at,
    "first_frame": Track.first_frame,
}


@dataclass(frozen=True)
class TrackFilter:
    sequence_id: int | None = None
    status: str | None = None
    label: str | None = None
    unlabelled: bool | None = None
    min_length: int | None = None
    max_length: int | None = None
    predicted_class: str | None = None
    min_confidence: float | None = None
    max_confidence: float | None = None
    ids: tuple[int, ...] | None = None  # only these track ids (the viewer asks for a frame's tracks)

    def clauses(self) -> list[Any]:
        c: list[Any] = []
        if self.ids is not None:
            c.append(Track.id.in_(self.ids))
        if self.sequence_id is not None:
            c.append(Track.sequence_id == self.sequence_id)
        if self.status is not None:
            c.append(Track.status == self.status)
        if self.label is not None:
            c.append(Track.label == self.label)
        if self.unlabelled is True:
            c.append(Track.label.is_(None))
        elif self.unlabelled is False:
            c.append(Track.label.is_not(None))
        if self.min_length is not None:
            c.append(Track.length >= self.min_length)
        if self.max_length is not None:
            c.append(Track.length <= self.max_length)
        if self.predicted_class is not None:
            c.append(Track.predicted_class == self.predicted_class)
        if self.min_confidence is not None:
            c.append(Track.predicted_confidence >= self.min_confidence)
        if self.max_confidence is not None:
            c.append(Track.predicted_confidence <= self.max_confidence)
        return c


def list_tracks(
    session: Session, flt: TrackFilter, sort: str, limit: int, offset: int
) -> tuple[list[dict[str, Any]], int]:
    """A page of tracks (column dicts, no ORM objects: a page is read, never changed) and the total
    matching `flt`. `sort` is a key of TRACK_SORTS, '-' = descending."""
    desc = sort.startswith("-")
    col = TRACK_SORTS[sort.lstrip("-")]
    clauses = flt.clauses()
    # NULLs last either way, identically on both databases. Only a nullable column says so: an
    # explicit NULLS LAST on a column without NULLs changes no result but keeps PostgreSQL from
    # walking its index backwards (it sorted all 50k rows for every "-length" page)
    key = col.desc() if desc else col.asc()
    order = [key.nulls_last() if col.nullable else key, Track.id.desc() if desc else Track.id.asc()]
    # the page's ids first (sorting narrow index entries, not whole rows), then those rows
    page = select(Track.id).where(*clauses).order_by(*order).limit(limit).offset(offset)
    table = Track.__table__
    rows = session.connection().execute(select(table).where(table.c.id.in_(page)).order_by(*order)).mappings().all()
    total = session.scalar(select(func.count()).select_from(Track).where(*clauses)) or 0
    return [dict(r) for r in rows], int(total)


def get_track(session: Session, track_id: int) -> Track:
    return get_or_404(session, Track, track_id, "track")


def track_segments(session: Session, track_id: int) -> list[Segment]:
    return list(
        session.scalars(select(Segment).where(Segment.track_id == track_id).order_by(Segment.frame_index)).all()
    )


def track_events(session: Session, track_id: int) -> list[AnnotationEvent]:
    return list(
        session.scalars(
            select(AnnotationEvent).where(AnnotationEvent.track_id == track_id).order_by(AnnotationEvent.id)
        ).all()
    )



def track_ranges(session: Session, sequence_id: int) -> list[Any]:
    """The sequence's tracks: id, keep_start, keep_end, n_points, status."""
    return list(session.execute(
        select(Track.id, Track.keep_start, Track.keep_end, Track.n_points, Track.status)
        .where(Track.sequence_id == sequence_id)
    ).all())


def set_predictions(session: Session, rows: list[dict[str, Any]]) -> None:
    """Write each track's `predicted_class`, `predicted_confidence` and `priority` (dicts with the
    track's `id`), in batches of 5000 rows; commits."""
    for i in range(0, len(rows), 5000):
        session.execute(update(Track), rows[i : i + 5000])
    session.commit()
