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
from pipeline.label_sets import DEFAULT_LABEL_SET, LabelSet
from pipeline.label_sets.model import Name

# ----------------------------------------------------------------------------- datasets
LabelSetName = Name  # the form of a label set's name, as pipeline.label_sets checks it
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
    label_set: LabelSetName | dict[str, Any] = Field(
        default=DEFAULT_LABEL_SET,
        description="Its classes: a preset's name (`tracklabel labelset list`; unknown: 422), or a label set "
                    "as data, the fields of a label set file (docs/label_sets.md; not valid: 422 naming the field).",
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
    label_set: str = Field(description="The name of the label set its classes come from (a preset, or the set "
                                       "given at registration): GET /sequences/{id}/label-set gives its classes.")
    ingest_job_id: int | None
    created_at: UtcDateTime


class LabelClassPublic(BaseModel):
    index: int = Field(description="The class index: the model's output index for a class that is not ground.")
    name: str
    colour: tuple[int, int, int] = Field(description="RGB, 0-255 each.")
    key: str | None = Field(description="Its hotkey in the annotator (None: none).")
    reads: list[int] = Field(description="The SemanticKITTI ids read as this class.")
    writes: int = Field(description="The SemanticKITTI id written for it.")
    moving: int | None = Field(description="The SemanticKITTI id written for its moving variant.")
    kind: Literal["thing", "stuff"]
    ground: bool


class LabelSetPublic(BaseModel):
    """A sequence's label set (pipeline/label_sets): its classes in index order, those that are not
    ground (a track's classes, the model's outputs) first."""

    name: str
    description: str
    classes: list[LabelClassPublic]
    sample_classes: list[str] = Field(description="The classes a track can take (not ground), in index order.")
    ground_classes: list[str]
    unlabelled_ids: list[int]
    fallback: str | None

    @classmethod
    def of(cls, label_set: LabelSet) -> LabelSetPublic:
        classes = [LabelClassPublic(index=i, **c.model_dump()) for i, c in enumerate(label_set.point_classes)]
        return cls(name=label_set.name, description=label_set.description, classes=classes,
                   sample_classes=list(label_set.sample_class_names),
                   ground_classes=[c.name for c in label_set.ground_classes],
                   unlabelled_ids=list(label_set.unlabelled_ids), fallback=label_set.fallback)


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
