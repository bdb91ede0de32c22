"""Datasets, sequences, assignments and frames."""

from __future__ import annotations

from typing import Any, Literal

from pydantic import BaseModel, Field

from app.schemas.base import (
    PATH_PATTERN,
    SequenceStatus,
    UtcDateTime,
    _Public,
    _Request,
)
from pipeline.label_sets import DEFAULT_LABEL_SET

# ----------------------------------------------------------------------------- datasets
IngestPoses = Literal["file", "icp"]
POSES_HELP = "Poses for ingest: file (the sequence's own; none links no tracks) or icp (estimated by KISS-ICP)."

class DatasetBase(_Request):
    path: str = Field(
        min_length=1, max_length=4096, pattern=PATH_PATTERN,
        description="A sequence path under a configured data root (no part longer than 255 characters).",
    )
    name: str | None = Field(default=None, max_length=128)
    format: str = Field(default="auto", max_length=32, pattern=r"^[a-z0-9_]+$")


class DatasetCreate(DatasetBase):
    ingest: bool = Field(default=True, description="Queue the ingest job right away.")
    config: dict[str, Any] | None = Field(default=None, description="Pipeline config overrides for ingest.")
    poses: IngestPoses = Field(default="file", description=POSES_HELP)
    reregister: bool = Field(
        default=False, description="Register the folder again although a sequence of it exists (else 409)."
    )
    label_set: str = Field(
        default=DEFAULT_LABEL_SET, min_length=1, max_length=64, pattern=r"^[a-z0-9][a-z0-9_-]*$",
        description="The preset label set of its classes (`tracklabel labelset list`); unknown: 422.",
    )


class AssignmentCreate(_Request):
    sequence_id: int = Field(ge=1, le=2**31 - 1)
    user_id: int = Field(ge=1, le=2**31 - 1)


class AssignmentPublic(_Public):
    id: int
    sequence_id: int
    user_id: int
    created_by_id: int | None
    created_at: UtcDateTime


class SequencePublic(_Public):
    id: int
    dataset_id: int
    name: str
    path: str | None = Field(description="The folder on the server (admins only).")
    format: str
    sensor: dict[str, Any] | None
    status: SequenceStatus
    n_frames: int
    label_set: str = Field(description="The label set its classes come from (a preset).")
    ingest_job_id: int | None
    created_at: UtcDateTime


class DatasetPublic(_Public):
    id: int
    name: str
    path: str
    created_at: UtcDateTime
    sequences: list[SequencePublic] = []


class SequenceStats(BaseModel):
    sequence: SequencePublic
    frames: int
    segments: int
    samples: int
    tracks: int
    tracks_by_status: dict[str, int]
    constraints: int


class DatasetDetail(DatasetPublic):
    stats: list[SequenceStats] = []


class IngestRequest(_Request):
    force: bool = Field(default=False, description="Re-ingest a ready sequence, dropping its reviews.")
    poses: IngestPoses = Field(default="file", description=POSES_HELP)


# ----------------------------------------------------------------------------- frames
class FramePublic(_Public):
    id: int
    sequence_id: int
    index: int
    name: str
    n_points: int
    n_segments: int
    n_samples: int
    timestamp: float | None
    pose: list[float] | None


class FrameList(BaseModel):
    items: list[FramePublic]
    total: int
