"""Jobs, job types, progress and health."""

from __future__ import annotations

from typing import Any, Literal

from pydantic import BaseModel, Field

from app.schemas.base import (
    JobStatus,
    UtcDateTime,
    _Public,
    _Request,
)


# ----------------------------------------------------------------------------- jobs
class JobBase(_Request):
    type: str = Field(min_length=1, max_length=32)
    params: dict[str, Any] = Field(default_factory=dict)


class JobCreate(JobBase):
    pass


class JobPublic(_Public):
    id: int
    type: str
    params: dict[str, Any]
    status: JobStatus
    progress: float
    message: str
    result: dict[str, Any] | None
    error: str | None
    created_by_id: int | None
    created_at: UtcDateTime
    started_at: UtcDateTime | None
    finished_at: UtcDateTime | None
    attempts: int
    cancel_requested: bool


class JobTypePublic(BaseModel):
    name: str
    admin_only: bool
    description: str
    params_schema: dict[str, Any]
    operators_may_queue: bool
    operator_max_values: dict[str, float] = Field(description="Upper bounds of params for operators.")
    admin_only_params: list[str] = Field(description="Switches only an admin may turn on.")
    max_run_seconds: float = Field(description="A job running longer is stopped and marked failed.")


# ----------------------------------------------------------------------------- exports
class AgreementRow(BaseModel):
    audited: int
    agreed: int
    agreement: float = Field(description="agreed / audited")


class ErrorRate(BaseModel):
    audited: int
    corrected: int
    error: float | None = Field(description="corrected / audited (None when nothing was audited).")
    ci95: tuple[float, float] = Field(description="95 % Wilson interval of the error.")


class ClassErrorRate(ErrorRate):
    bulk_tracks: int = Field(description="Tracks of the class accepted in bulk (audited or not).")


class BulkErrorStats(BaseModel):
    bulk_tracks: int = Field(description="Tracks accepted in bulk and still accepted.")
    bulk_tracks_per_class: dict[str, int]
    per_class: dict[str, ClassErrorRate] = Field(description="Audited bulk-accepted tracks by their bulk class.")
    overall: ErrorRate = Field(description="Over every audited bulk track: the error of bulk-accepted classes.")


class AuditStats(BaseModel):
    queued: int
    per_operator: dict[str, AgreementRow] = Field(description="By the name of the operator who accepted the track.")
    per_class: dict[str, AgreementRow] = Field(description="By the class the operator gave.")
    bulk: BulkErrorStats


class ProgressStats(BaseModel):
    tracks: int
    tracks_by_status: dict[str, int]
    tracks_reviewed: int
    samples: int
    samples_labelled: int
    samples_labelled_per_class: dict[str, int]
    constraints_automatic: int
    constraints_verified: int
    tracks_accepted_by_source: dict[str, int] = Field(description="Accepted tracks by where the class came from.")
    samples_labelled_per_source: dict[str, int]
    bulk_actions: int = Field(description="Bulk accepts (undone ones included).")
    operations: int | None = Field(description="Label-changing operations on the sequence (None over all sequences).")
    label_set: str | None = Field(default=None, description="The sequence's label set (None over all sequences).")
    classes: list[str] = Field(default=[], description="The classes samples are labelled in: its label set's, in index order.")
    audit: AuditStats


class Health(BaseModel):
    status: Literal["ok"]
    database: str
    version: str
