"""Anchors, stitches, audits and ground regions: the proposals, checks and regions an operator decides."""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, Field, model_validator

from app.schemas.base import (
    ClassName,
    LabelSource,
    UtcDateTime,
    _Public,
    _Request,
)
from app.schemas.tracks import Finite as WorldCoordinate

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


# ----------------------------------------------------------------------------- ground regions
class GroundRegionCreate(_Request):
    """A polygon on the top view (world x, y in metres, 3 to 1000 vertices, not closed) and the
    class of the sequence's label set its points take: its ground points that no decided track
    holds, or with `z_min` and `z_max` every point of the prism between them, a decided track's
    too (the prism of a split's region). With `frame_index` only that frame's points; with
    `clip_from_world` as well the polygon is a lasso drawn in that frame's view (normalised
    device coordinates of the camera, x right and y up in -1..1) and every point of the frame it
    holds takes the class, whatever holds it: the points no track, prism or radius separates."""

    class_name: str = Field(min_length=1, max_length=32)
    polygon: list[tuple[WorldCoordinate, WorldCoordinate]] = Field(min_length=3, max_length=1000)
    z_min: WorldCoordinate | None = Field(default=None, description="World z (m), with z_max: the prism's bottom.")
    z_max: WorldCoordinate | None = Field(default=None, description="World z (m), with z_min: the prism's top.")
    frame_index: int | None = Field(default=None, ge=0, le=2**31 - 1,
                                    description="The sequence's frame whose points alone the region labels.")
    clip_from_world: list[WorldCoordinate] | None = Field(
        default=None, min_length=16, max_length=16,
        description="With frame_index: the 4x4 row-major matrix of the camera the lasso was drawn with; a point "
                    "counts in front of it, between its near and far planes (-w <= clip z <= w).")

    @model_validator(mode="after")
    def _both_heights(self) -> GroundRegionCreate:
        if (self.z_min is None) != (self.z_max is None):
            raise ValueError("z_min and z_max: give both or neither")
        if self.z_min is not None and self.z_max is not None and not self.z_min < self.z_max:
            raise ValueError(f"z_min {self.z_min} must be below z_max {self.z_max}")
        if self.clip_from_world is not None and self.frame_index is None:
            raise ValueError("clip_from_world: a lasso in a view needs the frame_index it was drawn on")
        return self

    @property
    def heights(self) -> tuple[float, float] | None:
        return None if self.z_min is None or self.z_max is None else (self.z_min, self.z_max)


class GroundRegionPublic(_Public):
    """A stored region: the ground points inside its polygon (with `z_min` and `z_max`, every
    point inside the prism; with `clip_from_world`, every point of its frame inside the lasso)
    take `class_name` in every frame of the sequence's exports (with `frame_index`, in that
    frame); the newest region wins where regions overlap."""

    id: int
    sequence_id: int
    class_name: str
    polygon: list[tuple[float, float]]
    z_min: float | None
    z_max: float | None
    frame_index: int | None = Field(default=None, description="The one frame it labels (None: every frame).")
    clip_from_world: list[float] | None = Field(
        default=None, description="The camera of a lasso drawn in a frame's view (polygon in its device coordinates).")
    created_by_id: int | None
    created_at: UtcDateTime
