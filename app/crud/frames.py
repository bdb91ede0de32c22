"""Frames of a sequence and the artifact files that hold their arrays."""

from __future__ import annotations

from typing import Any

from sqlalchemy import func, select
from sqlalchemy.orm import Session

from app.core.errors import NotFound
from app.crud.rows import get_or_404
from app.models import Frame, Segment, Sequence


def list_frames(session: Session, sequence_id: int, limit: int, offset: int) -> tuple[list[Frame], int]:
    """A page of a sequence's frames in order and how many it has (only frames whose ingest batch
    committed); NotFound for an unknown sequence."""
    if session.get(Sequence, sequence_id) is None:
        raise NotFound(f"sequence {sequence_id} not found")
    rows = session.scalars(
        select(Frame).where(Frame.sequence_id == sequence_id).order_by(Frame.index).limit(limit).offset(offset)
    ).all()
    total = session.scalar(select(func.count()).select_from(Frame).where(Frame.sequence_id == sequence_id)) or 0
    return list(rows), int(total)


def get_frame(session: Session, frame_id: int) -> Frame:
    return get_or_404(session, Frame, frame_id, "frame")


def frame_artifact(session: Session, frame_id: int) -> str:
    """The frame's artifact file (relative to the artifact root)."""
    rel = session.scalar(select(Frame.artifact).where(Frame.id == frame_id))
    if rel is None:
        raise NotFound(f"frame {frame_id} not found")
    return rel


def segment_sample_ref(session: Session, segment_id: int) -> tuple[str, int]:
    """(artifact file, sample index) of a segment's sample; NotFound when it has none."""
    row = session.execute(
        select(Segment.sample_index, Frame.artifact).join(Frame, Frame.id == Segment.frame_id).where(Segment.id == segment_id)
    ).first()
    if row is None or row.sample_index is None:
        raise NotFound(f"segment {segment_id} has no sample")
    return row.artifact, int(row.sample_index)


def frame_artifacts(session: Session, sequence_id: int) -> dict[int, str]:
    """The artifact file of each of the sequence's frames, by frame id."""
    return {int(i): a for i, a in session.execute(select(Frame.id, Frame.artifact).where(Frame.sequence_id == sequence_id))}


def sample_segments(session: Session, sequence_id: int) -> list[Any]:
    """The sequence's segments that have a sample, in frame order then sample order: id, frame_id,
    frame_index, sample_index, track_id, n_points, range, cz."""
    return list(session.execute(
        select(Segment.id, Segment.frame_id, Segment.frame_index, Segment.sample_index, Segment.track_id,
               Segment.n_points, Segment.range, Segment.cz)
        .where(Segment.sequence_id == sequence_id, Segment.sample_index.is_not(None))
        .order_by(Segment.frame_index, Segment.sample_index)
    ).all())

