"""Pydantic request/response schemas: `XBase`, `XCreate`, `XUpdate`, `XPublic` per resource.

Routes return these, never table models.
"""

from __future__ import annotations

from datetime import UTC, datetime
from types import UnionType
from typing import Annotated, Any, Literal, Union, get_args, get_origin

from pydantic import AfterValidator, BaseModel, ConfigDict, Field, model_validator

from pipeline.classes import SAMPLE_CLASSES

Role = Literal["operator", "reviewer", "admin"]
TrackStatus = Literal["pending", "accepted", "discarded", "merged"]
JobStatus = Literal["queued", "running", "succeeded", "failed", "cancelled"]
SequenceStatus = Literal["registered", "ingesting", "ready", "failed"]
ClassName = Literal["person", "car", "cyclist", "trunk", "bush", "building", "unknown"]
LabelSource = Literal["review", "bulk"]
assert set(ClassName.__args__) == set(SAMPLE_CLASSES)  # type: ignore[attr-defined]


def _as_utc(value: datetime) -> datetime:
    """The tables hold naive UTC (app.models.utcnow); the API says so: RFC 3339 with `Z`."""
    return value.replace(tzinfo=UTC) if value.tzinfo is None else value.astimezone(UTC)


UtcDateTime = Annotated[datetime, AfterValidator(_as_utc)]


class _Public(BaseModel):
    model_config = ConfigDict(from_attributes=True)


class JsonModel(BaseModel):
    """A request body (or job params) read as JSON Schema reads it: a number field takes a JSON
    number only, an integer field a number without fraction (`1` or `1.0`: JSON Schema counts
    `1.0` an integer, and refusing it would break the declared schema; `1.5` and `"1"` are 422),
    a boolean field `true` or `false` only. Pydantic's lax mode would coerce `"1"` or `"yes"`;
    the schema promises they are refused (`{"version": "1"}` gets 422). No string field holds a
    NUL byte (PostgreSQL cannot store one; 422 instead of a 500)."""

    model_config = ConfigDict(extra="forbid")

    @model_validator(mode="before")
    @classmethod
    def _json_scalars(cls, data: Any) -> Any:
        # a model validator, not a field one: pydantic refuses field validators on the
        # discriminator fields of tagged unions (SplitRegion's `kind`)
        if not isinstance(data, dict):
            return data
        for name, value in data.items():
            if _holds_nul(value):
                raise ValueError(f"{name} holds a NUL byte")
            field = cls.model_fields.get(name)
            if field is None or value is None:
                continue
            kinds = _scalar_kinds(field.annotation)
            if bool in kinds and not isinstance(value, bool) and not kinds & {int, float}:
                raise ValueError(f"{name} must be true or false, not {type(value).__name__}")
            if kinds & {int, float} and bool not in kinds and isinstance(value, str | bool):
                raise ValueError(f"{name} must be a JSON number, not {type(value).__name__}")
        return data


def _holds_nul(value: Any) -> bool:
    """True for a string (or list of strings) with a NUL byte. Free-form JSON values (configs,
    results) may hold one: they are stored as JSON text, escaped."""
    if isinstance(value, str):
        return "\x00" in value
    return isinstance(value, list) and any(isinstance(v, str) and "\x00" in v for v in value)


# no NUL byte, and no part between slashes longer than NAME_MAX (255; a longer one is 422, not
# the file system's error). Linear to match: each repeated part must end at a slash.
PATH_PATTERN = r"^/*([^/\x00]{1,255}/+)*[^/\x00]{0,255}$"


def _scalar_kinds(annotation: Any) -> set[type]:
    """The scalar types an annotation admits (`int | None` -> {int}); empty for anything else."""
    args = get_args(annotation) if get_origin(annotation) in (Union, UnionType) else (annotation,)
    return {a for a in args if a in (int, float, bool)}


_Request = JsonModel


class UserBase(_Request):
    name: str = Field(min_length=1, max_length=64, pattern=r"^[A-Za-z0-9_.@-]+$")
    role: Role = "operator"


EXPIRES_HELP = "Days the token is valid; the service's token_expiry_days (90) when omitted."


class UserCreate(UserBase):
    expires_days: float | None = Field(default=None, gt=0, le=36500, description=EXPIRES_HELP)


class TokenCreate(_Request):
    expires_days: float | None = Field(default=None, gt=0, le=36500, description=EXPIRES_HELP)


class TokenPublic(_Public):
    id: int
    prefix: str = Field(description="The token's first characters (to tell tokens apart, and to revoke one).")
    created_at: UtcDateTime
    created_by_id: int | None
    expires_at: UtcDateTime | None
    revoked_at: UtcDateTime | None


class TokenRevoke(_Request):
    prefix: str = Field(min_length=6, max_length=64, description="Revoke the live tokens starting with this.")


class RevokeResult(BaseModel):
    revoked: int


class UserPublic(_Public):
    id: int
    name: str
    role: Role
    active: bool
    created_at: UtcDateTime


class UserWithToken(BaseModel):
    user: UserPublic
    token: str = Field(description="Shown once; only its hash is stored.")


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


# ----------------------------------------------------------------------------- tracks
class TrackPublic(_Public):
    id: int
    sequence_id: int
    key: int
    status: TrackStatus
    first_frame: int
    last_frame: int
    keep_start: int
    keep_end: int
    length: int
    n_samples: int
    n_points: int
    mean_range: float
    label: str | None
    predicted_class: str | None
    predicted_confidence: float | None
    label_source: LabelSource | None = Field(
        default=None, description="Where an accepted class came from: an operator's review, or a bulk accept.")
    priority: float = Field(default=0.0, description="Queue order, highest first: points the review is expected to correct.")
    version: int
    updated_at: UtcDateTime
    lease_expires_at: UtcDateTime | None = None


class BulkAcceptAction(_Request):
    class_name: ClassName = Field(description="Accept the pending tracks predicted as this class ...")
    min_confidence: float = Field(ge=0.0, le=1.0, allow_inf_nan=False, description="... with at least this confidence.")
    expected_tracks: int | None = Field(
        default=None, ge=0, le=2**31 - 1,
        description="The count the preview showed; another count now (the predictions changed) -> 409.")


class BulkPreview(BaseModel):
    sequence_id: int
    class_name: str
    min_confidence: float
    tracks: int
    points: int
    confidence_min: float | None
    confidence_mean: float | None
    largest_track_ids: list[int]
    held_out_precision: float | None = Field(description=(
        "Of the reviewed tracks the model in the loop predicted as this class at this confidence with the track "
        "left out of its fit, the share that was right (None before any run or when none was)."))
    held_out_tracks: int = Field(description="How many reviewed tracks that share is over.")


class BulkActionPublic(_Public):
    id: int
    sequence_id: int
    user_id: int | None
    class_name: str
    min_confidence: float
    n_tracks: int
    n_points: int
    created_at: UtcDateTime
    undone_at: UtcDateTime | None
    undone_by_id: int | None


class TrackList(BaseModel):
    items: list[TrackPublic]
    total: int
    limit: int
    offset: int


class SegmentPublic(_Public):
    id: int
    frame_id: int
    frame_index: int
    local_id: int
    n_points: int
    centroid: tuple[float, float, float]
    centroid_world: tuple[float, float, float]
    range: float
    valid: bool
    link_score: float | None
    in_kept_range: bool
    sample_url: str | None


class TrackDetail(TrackPublic):
    segments: list[SegmentPublic]


class ActionBase(_Request):
    version: int = Field(ge=1, le=2**31 - 1, description="The track version the action was decided on.")


class AcceptAction(ActionBase):
    pass


class DiscardAction(ActionBase):
    pass


class UndoAction(ActionBase):
    pass


class TruncateAction(ActionBase):
    start: int = Field(ge=0, le=2**31 - 1, description="First kept frame index.")
    end: int = Field(ge=0, le=2**31 - 1, description="Last kept frame index (inclusive).")


class LabelAction(ActionBase):
    label: ClassName = Field(description="One of the sample classes.")


Finite = Annotated[float, Field(allow_inf_nan=False, ge=-1e7, le=1e7)]
Vec3 = tuple[Finite, Finite, Finite]
Size = Annotated[float, Field(allow_inf_nan=False, gt=0, le=1e4)]


class BoxRegion(_Request):
    """A box in the world frame: centre, full extents along its own axes, orientation (w, x, y, z)."""

    kind: Literal["box"]
    center: Vec3
    size: tuple[Size, Size, Size]
    wxyz: tuple[Finite, Finite, Finite, Finite] = (1.0, 0.0, 0.0, 0.0)


class HalfSpaceRegion(_Request):
    """World points p with normal . p >= offset."""

    kind: Literal["halfspace"]
    normal: Vec3
    offset: Finite


class PrismRegion(_Request):
    """A world x-y polygon (drawn in the top view) extruded from z_min to z_max."""

    kind: Literal["prism"]
    polygon: list[tuple[Finite, Finite]] = Field(min_length=3, max_length=1000)
    z_min: Finite = -1e4
    z_max: Finite = 1e4


class LassoRegion(_Request):
    """A screen polygon in normalised device coordinates (-1..1, y up) with the 4x4 row-major
    `clip_from_world` matrix of the camera it was drawn with."""

    kind: Literal["lasso"]
    polygon: list[tuple[Finite, Finite]] = Field(min_length=3, max_length=1000)
    clip_from_world: list[Finite] = Field(min_length=16, max_length=16)


class HeightRegion(_Request):
    """The track's points at least `min_height` metres above the ground."""

    kind: Literal["height"]
    min_height: float = Field(ge=-10.0, le=100.0)


class PredictedRegion(_Request):
    """The track's kept segments that model `model_id` classifies as `class_name` (whole segments)."""

    kind: Literal["predicted"]
    model_id: int = Field(ge=1, le=2**31 - 1)
    class_name: str = Field(min_length=1, max_length=16)


SplitRegion = Annotated[
    BoxRegion | HalfSpaceRegion | PrismRegion | LassoRegion | HeightRegion | PredictedRegion, Field(discriminator="kind")
]


class SplitAction(ActionBase):
    region: SplitRegion
    frame_index: int | None = Field(
        default=None, ge=0, le=2**31 - 1, description="Cut in this frame only; omitted: in every kept frame."
    )


class MergeAction(ActionBase):
    other_track_id: int = Field(ge=1, le=2**62, description="The track joined into this one.")
    other_version: int = Field(ge=1, le=2**31 - 1, description="The other track's version.")


class SplitPublic(BaseModel):
    track: TrackPublic
    new_track: TrackPublic
    moved_points: int


class EventPublic(_Public):
    id: int
    track_id: int
    user_id: int | None
    action: str
    created_at: UtcDateTime
    version_before: int
    version_after: int
    before: dict[str, Any]
    after: dict[str, Any]
    reverts_event_id: int | None
    detail: dict[str, Any] | None = None


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
    audit: AuditStats


class Health(BaseModel):
    status: Literal["ok"]
    database: str
    version: str


# ----------------------------------------------------------------------------- anchors (issue 7)
AnchorStatus = Literal["proposed", "confirmed", "rejected"]
AnchorLevel = Literal["sample", "track"]


class AnchorPublic(BaseModel):
    """A proposed fine-tuning anchor: one sample (`level` sample) or a whole track (`level` track,
    `segment_id` = a representative sample to show)."""

    id: int
    sequence_id: int
    track_id: int
    segment_id: int | None
    frame_index: int | None = Field(description="Frame of the (representative) sample.")
    level: AnchorLevel
    strategy: str | None
    rank: int | None = Field(description="Order within its proposed class, 0 = proposed first.")
    proposed_class: str | None
    score: float = Field(description="The strategy's score (confidence, entropy or k-center distance).")
    status: AnchorStatus
    answer_class: str | None = Field(description="The class the operator gave (confirm or correct).")
    corrected: bool = Field(description="Confirmed with a class other than the proposed one.")
    decided_by_id: int | None
    decided_by: str | None
    decided_at: UtcDateTime | None
    model_id: int | None = Field(description="The model version that proposed it.")
    job_id: int | None = Field(description="The propose_anchors job that made it.")
    created_at: UtcDateTime
    sample_url: str | None = Field(description="PNG of the (representative) sample.")


class AnchorList(BaseModel):
    items: list[AnchorPublic]
    total: int
    limit: int
    offset: int


class AnchorCorrect(_Request):
    label: ClassName = Field(description="The right class (one of the sample classes).")


class AnchorClassCounts(BaseModel):
    proposed: int = 0
    confirmed: int = 0
    corrected: int = 0
    rejected: int = 0


class AnchorSummary(BaseModel):
    total: int
    by_status: dict[str, int]
    per_class: dict[str, AnchorClassCounts] = Field(
        description="proposed/rejected/corrected by proposed class; confirmed by answer class."
    )


class AnchorEventPublic(_Public):
    id: int
    proposal_id: int
    sequence_id: int
    user_id: int | None
    action: Literal["confirm", "correct", "reject"]
    class_name: str | None
    created_at: UtcDateTime


# ----------------------------------------------------------------------------- stitches (issue 5)
StitchStatus = Literal["pending", "confirmed", "rejected"]


class StitchPublic(_Public):
    """Two tracks joined by the association's fragment links (pieces of one object that split,
    merged or reshuffled between frames). Confirmed: one object; its fragment pairs become
    verified constraints once both tracks are accepted."""

    id: int
    sequence_id: int
    track_a_id: int
    track_b_id: int
    links: int = Field(description="Fragment pairs joining the two tracks.")
    share: float = Field(description="Largest share of a segment's points shared by a linked pair.")
    status: StitchStatus
    version: int
    decided_by_id: int | None
    decided_at: UtcDateTime | None


class StitchList(BaseModel):
    items: list[StitchPublic]
    total: int
    limit: int
    offset: int


class StitchDecision(_Request):
    version: int = Field(ge=1, le=2**31 - 1, description="The stitch version the decision was made on.")


# ----------------------------------------------------------------------------- audits (issue 23)
AuditStatus = Literal["queued", "agreed", "corrected"]


class AuditSample(_Request):
    n: int = Field(ge=1, le=10_000, description="Accepted, never-audited tracks to queue (fewer when fewer exist).")
    sequence_id: int | None = Field(default=None, ge=1, le=2**31 - 1, description="One sequence; all when omitted.")
    seed: int = Field(default=0, ge=0, le=2**31 - 1)
    source: LabelSource | None = Field(default=None, description="Only tracks whose class came from this source "
                                       "(`bulk`: bulk-accepted predictions); any when omitted.")


class AuditCorrect(_Request):
    label: ClassName = Field(description="The right class of the track.")


class AuditPublic(_Public):
    id: int
    sequence_id: int
    track_id: int
    operator_id: int | None = Field(description="Who accepted the track.")
    label: str | None = Field(description="The class the operator gave.")
    status: AuditStatus
    sampled_by_id: int | None
    created_at: UtcDateTime
    auditor_id: int | None
    answer_label: str | None = Field(description="The auditor's class (the operator's when agreed).")
    decided_at: UtcDateTime | None
    source: LabelSource | None = Field(default=None, description="The label's source when sampled.")
