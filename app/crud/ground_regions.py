"""Ground regions: polygons an operator draws on a sequence's top view, each with a class of the
sequence's label set. The exports give the ground points inside them that class in every frame,
or with a height range every point inside the prism (`pipeline.propagation`); the newest region
wins where regions overlap; deleting one undoes it (the row stays, marked deleted, for the count
of operations)."""

from __future__ import annotations

import math

from sqlalchemy import func, select
from sqlalchemy.orm import Session

from app.core.errors import Invalid, NotFound
from app.crud.datasets import get_sequence
from app.crud.label_sets import check_class, label_set_of
from app.crud.users import AuthUser
from app.models import Frame, GroundRegion, utcnow


def create_region(session: Session, sequence_id: int, user: AuthUser, class_name: str,
                  polygon: list[tuple[float, float]], heights: tuple[float, float] | None = None,
                  frame_index: int | None = None, clip_from_world: list[float] | None = None) -> GroundRegion:
    """Store a region (NotFound for an unknown sequence, Invalid for a class outside its label
    set, a polygon without area, heights (z_min, z_max) out of order, a frame the sequence does
    not have, or a view without its frame or whose matrix is not 16 finite numbers). Commits."""
    seq = get_sequence(session, sequence_id)
    check_class("class_name", class_name, label_set_of(seq), ground=True)
    if _area(polygon) <= (1e-9 if clip_from_world is not None else 1e-6):  # device units, or m²
        raise Invalid("polygon: its vertices enclose no area")
    if heights is not None and not heights[0] < heights[1]:
        raise Invalid(f"z_min {heights[0]} must be below z_max {heights[1]}")
    _check_view(session, sequence_id, frame_index, clip_from_world)
    low, high = (None, None) if heights is None else (float(heights[0]), float(heights[1]))
    row = GroundRegion(sequence_id=sequence_id, class_name=class_name, polygon=[[float(x), float(y)] for x, y in polygon],
                       z_min=low, z_max=high, frame_index=frame_index,
                       clip_from_world=None if clip_from_world is None else [float(v) for v in clip_from_world],
                       created_by_id=user.id)
    session.add(row)
    session.commit()
    return row


def _check_view(session: Session, sequence_id: int, frame_index: int | None, clip_from_world: list[float] | None) -> None:
    """Invalid for a view without its frame, a matrix that is not 16 finite numbers, or a frame
    the sequence does not have."""
    if clip_from_world is not None:
        if frame_index is None:
            raise Invalid("clip_from_world: a lasso in a view needs the frame_index it was drawn on")
        if len(clip_from_world) != 16 or not all(math.isfinite(float(v)) for v in clip_from_world):
            raise Invalid("clip_from_world: 16 finite numbers, a 4x4 matrix row by row")
    if frame_index is not None and session.scalar(
            select(Frame.id).where(Frame.sequence_id == sequence_id, Frame.index == frame_index)) is None:
        raise Invalid(f"frame_index: sequence {sequence_id} has no frame {frame_index}")


def _area(polygon: list[tuple[float, float]]) -> float:
    """Absolute shoelace area (m²)."""
    xs, ys = [p[0] for p in polygon], [p[1] for p in polygon]
    return abs(sum(xs[i] * ys[i - 1] - xs[i - 1] * ys[i] for i in range(len(xs)))) / 2.0


def _live(sequence_id: int) -> tuple:
    """The sequence's regions that are not undone (an undone one stays, marked deleted)."""
    return GroundRegion.sequence_id == sequence_id, GroundRegion.deleted_at.is_(None)


def list_regions(session: Session, sequence_id: int) -> list[GroundRegion]:
    """A sequence's regions, oldest first (the order they are drawn in)."""
    return list(session.scalars(select(GroundRegion).where(*_live(sequence_id)).order_by(GroundRegion.id)).all())


def region_ids(session: Session, sequence_id: int) -> list[int]:
    """The ids of list_regions, without reading the polygons (the change feed asks every second)."""
    return list(session.scalars(select(GroundRegion.id).where(*_live(sequence_id)).order_by(GroundRegion.id)).all())


def delete_region(session: Session, region_id: int, user: AuthUser) -> GroundRegion:
    """Undo a region (NotFound when there is none, or it was deleted already). Commits."""
    row = session.get(GroundRegion, region_id)
    if row is None or row.deleted_at is not None:
        raise NotFound(f"ground region {region_id} not found")
    row.deleted_at, row.deleted_by_id = utcnow(), user.id
    session.commit()
    return row


def region_operations(session: Session, sequence_id: int) -> int:
    """Label-changing requests on a sequence's ground regions: each drawn, each deleted."""
    drawn, deleted = session.execute(select(func.count(), func.count(GroundRegion.deleted_at))
                                     .where(GroundRegion.sequence_id == sequence_id)).one()
    return int(drawn) + int(deleted)
