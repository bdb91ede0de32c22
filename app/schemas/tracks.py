"""Tracks, their segments and events, review actions and the repair regions."""

from __future__ import annotations

from typing import Annotated, Any, Literal

from pydantic import BaseModel, Field

from app.schemas.base import (
    ClassName,
    LabelSource,
    TrackStatus,
    UtcDateTime,
    _Public,
    _Request,
)


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
    min_points: int | None = Field(description=(
        "Tracks with fewer points are left out: the smallest of those held-out reviewed tracks, below which the "
        "share says nothing (None: no floor, before any run)."))


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
