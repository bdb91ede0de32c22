"""What changed in a sequence since a moment (the viewer's change feed) and its progress in points."""

from __future__ import annotations

from pydantic import BaseModel, Field

from app.schemas.base import UtcDateTime


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
    cursor: UtcDateTime  # pass back as `since` (RFC 3339, UTC)
    tracks: list[TrackVersion]
    frames: list[FrameVersion]
    truncated: bool  # more than MAX_TRACKS tracks changed: drop every cache of the sequence
    region_ids: list[int] = Field(default_factory=list, description="The ids of the sequence's live ground regions, "
                                  "ascending (every answer): a viewer showing other ones re-reads them.")


class PointsProgress(BaseModel):
    sequence_id: int
    points: int = Field(description="All points of the sequence's frames (ground included).")
    points_in_tracks: int = Field(description="Points of the kept frames of its tracks (merged-away ones excluded).")
    points_labelled: int = Field(description="Of those, points of accepted tracks with a class.")
    points_labelled_per_source: dict[str, int]
    points_accepted_unlabelled: int
    points_discarded: int
    points_pending: int
