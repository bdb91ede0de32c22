"""Clearing and maintaining the tables an ingest bulk-loads."""

from __future__ import annotations

from sqlalchemy import Engine, delete, select, text, update
from sqlalchemy.orm import Session

from app.models import AnchorProposal, AnnotationEvent, Frame, Label, PairConstraint, Segment, Stitch, Track


def clear_sequence_rows(session: Session, sequence_id: int) -> None:
    """Delete everything ingest wrote for a sequence (children first). Does not commit."""
    tracks = select(Track.id).where(Track.sequence_id == sequence_id)
    session.execute(delete(Label).where(Label.sequence_id == sequence_id))
    session.execute(delete(AnchorProposal).where(AnchorProposal.sequence_id == sequence_id))
    session.execute(delete(PairConstraint).where(PairConstraint.sequence_id == sequence_id))
    session.execute(delete(Stitch).where(Stitch.sequence_id == sequence_id))
    session.execute(update(AnnotationEvent).where(AnnotationEvent.track_id.in_(tracks)).values(reverts_event_id=None))
    session.execute(delete(AnnotationEvent).where(AnnotationEvent.track_id.in_(tracks)))
    session.execute(delete(Segment).where(Segment.sequence_id == sequence_id))
    session.execute(delete(Track).where(Track.sequence_id == sequence_id))
    session.execute(delete(Frame).where(Frame.sequence_id == sequence_id))


BULK_TABLES = ("tracks", "segments", "constraints", "stitches", "frames")


def analyze_tables(session: Session) -> None:
    """Refresh the planner's statistics after a bulk load (ingest): on SQLite, without them a filter
    on a low-cardinality column (status) is taken as selective and a 50k-row sort follows."""
    for table in BULK_TABLES:
        session.execute(text(f"ANALYZE {table}"))


def vacuum_after_bulk_load(engine: Engine) -> None:
    """PostgreSQL: VACUUM the freshly loaded tables (outside any transaction), so that their
    visibility map lets counts and id pages come from the indexes alone. Without it every
    `GET /tracks` counted 50k tracks by reading the whole table (6-7 ms) until autovacuum came by.
    Nothing to do on SQLite."""
    if engine.dialect.name != "postgresql":
        return
    with engine.connect().execution_options(isolation_level="AUTOCOMMIT") as conn:
        conn.execute(text(f"VACUUM (ANALYZE) {', '.join(BULK_TABLES)}"))
