"""SQLAlchemy 2 tables. Heavy arrays never live here: a frame row points at its artifact file.

Times are naive UTC (`utcnow()`), identical on SQLite and PostgreSQL. Constraint names come from
`NAMING_CONVENTION`, so migrations name them the same on both databases.
"""

from __future__ import annotations

from datetime import UTC, datetime
from typing import Any

from sqlalchemy import (
    JSON,
    BigInteger,
    Boolean,
    CheckConstraint,
    DateTime,
    Float,
    ForeignKey,
    Index,
    Integer,
    MetaData,
    String,
    Text,
    UniqueConstraint,
    text,
)
from sqlalchemy.orm import DeclarativeBase, Mapped, mapped_column

from pipeline.label_sets import DEFAULT_LABEL_SET

NAMING_CONVENTION = {
    "ix": "ix_%(column_0_label)s",
    "uq": "uq_%(table_name)s_%(column_0_N_name)s",
    "ck": "ck_%(table_name)s_%(constraint_name)s",
    "fk": "fk_%(table_name)s_%(column_0_name)s_%(referred_table_name)s",
    "pk": "pk_%(table_name)s",
}

# 64-bit ids on PostgreSQL; SQLite needs INTEGER PRIMARY KEY to alias the rowid.
BigId = BigInteger().with_variant(Integer(), "sqlite")

ROLES = ("operator", "reviewer", "admin")  # reviewer: audits accepted tracks (migration 0008)
# merged: the track's segments were joined into another track (app/services/repair.py); undo brings them back
TRACK_STATUSES = ("pending", "accepted", "discarded", "merged")
SEQUENCE_STATUSES = ("registered", "ingesting", "ready", "failed")
JOB_STATUSES = ("queued", "running", "succeeded", "failed", "cancelled")
# bulk_accept: one of the tracks a bulk accept labelled (app/crud/bulk.py; its `BulkAction` row is the
# operation, the per-track events make undo and replay work as for any action)
ACTIONS = ("accept", "discard", "truncate", "label", "undo", "split", "merge", "bulk_accept")
# where an accepted track's class came from: an operator's own review, or a bulk accept of predictions
LABEL_SOURCES = ("review", "bulk")
ANCHOR_LEVELS = ("sample", "track")
ANCHOR_ACTIONS = ("confirm", "correct", "reject")


def utcnow() -> datetime:
    """Naive UTC now (the only clock the tables use)."""
    return datetime.now(UTC).replace(tzinfo=None)


def _in(column: str, values: tuple[str, ...]) -> str:
    return f"{column} IN ({', '.join(repr(v) for v in values)})"


class Base(DeclarativeBase):
    metadata = MetaData(naming_convention=NAMING_CONVENTION)


class User(Base):
    __tablename__ = "users"
    __table_args__ = (CheckConstraint(_in("role", ROLES), name="role"),)

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    name: Mapped[str] = mapped_column(String(64), unique=True)
    role: Mapped[str] = mapped_column(String(16))
    active: Mapped[bool] = mapped_column(Boolean, default=True)
    created_at: Mapped[datetime] = mapped_column(DateTime, default=utcnow)
    created_by_id: Mapped[int | None] = mapped_column(ForeignKey("users.id", ondelete="SET NULL"))


class ApiToken(Base):
    """A bearer token, stored as its SHA-256 (tokens are 256-bit random, so no slow hash is needed)."""

    __tablename__ = "api_tokens"

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    user_id: Mapped[int] = mapped_column(ForeignKey("users.id", ondelete="CASCADE"), index=True)
    token_hash: Mapped[str] = mapped_column(String(64), unique=True)
    prefix: Mapped[str] = mapped_column(String(16))
    created_at: Mapped[datetime] = mapped_column(DateTime, default=utcnow)
    # who issued it: an admin through the API, None for the CLI (`tracklabel user add`) and seeding
    created_by_id: Mapped[int | None] = mapped_column(ForeignKey("users.id", ondelete="SET NULL"))
    revoked_at: Mapped[datetime | None] = mapped_column(DateTime)
    # migration 0008: refused from then on (None = never, for tokens issued before expiry existed)
    expires_at: Mapped[datetime | None] = mapped_column(DateTime)


class Dataset(Base):
    __tablename__ = "datasets"

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    name: Mapped[str] = mapped_column(String(128))
    path: Mapped[str] = mapped_column(Text)
    created_at: Mapped[datetime] = mapped_column(DateTime, default=utcnow)
    created_by_id: Mapped[int | None] = mapped_column(ForeignKey("users.id", ondelete="SET NULL"))


class Sequence(Base):
    __tablename__ = "sequences"
    __table_args__ = (CheckConstraint(_in("status", SEQUENCE_STATUSES), name="status"),)

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    dataset_id: Mapped[int] = mapped_column(ForeignKey("datasets.id", ondelete="CASCADE"), index=True)
    name: Mapped[str] = mapped_column(String(128))
    path: Mapped[str] = mapped_column(Text)
    format: Mapped[str] = mapped_column(String(32))
    sensor: Mapped[dict[str, Any] | None] = mapped_column(JSON)
    config: Mapped[dict[str, Any] | None] = mapped_column(JSON)  # pipeline overrides for ingest
    status: Mapped[str] = mapped_column(String(16), default="registered")
    n_frames: Mapped[int] = mapped_column(Integer, default=0)
    # migration 0010: the highest track key handed out (app/crud/track_ids.py); a split's new track
    # takes the next one under this row's lock, so a key is never given twice, even after undo
    last_track_key: Mapped[int] = mapped_column(BigInteger, default=0, server_default="0")
    # migration 0012: the label set its classes come from (a preset, pipeline/label_sets)
    label_set: Mapped[str] = mapped_column(String(64), default=DEFAULT_LABEL_SET, server_default=DEFAULT_LABEL_SET)
    # migration 0013: a label set given as data at registration (its YAML fields); None: the
    # preset named by `label_set`
    label_set_definition: Mapped[dict[str, Any] | None] = mapped_column(JSON)
    ingest_job_id: Mapped[int | None] = mapped_column(ForeignKey("jobs.id", ondelete="SET NULL"))
    created_at: Mapped[datetime] = mapped_column(DateTime, default=utcnow)


class Frame(Base):
    __tablename__ = "frames"
    __table_args__ = (UniqueConstraint("sequence_id", "index"),)

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    sequence_id: Mapped[int] = mapped_column(ForeignKey("sequences.id", ondelete="CASCADE"))
    index: Mapped[int] = mapped_column(Integer)
    name: Mapped[str] = mapped_column(String(128))
    n_points: Mapped[int] = mapped_column(Integer)
    n_segments: Mapped[int] = mapped_column(Integer)
    n_samples: Mapped[int] = mapped_column(Integer)
    artifact: Mapped[str] = mapped_column(String(255))  # path relative to the artifact dir
    timestamp: Mapped[float | None] = mapped_column(Float)
    pose: Mapped[list[float] | None] = mapped_column(JSON)  # T_world_lidar, 16 floats row-major


TRACK_SORT_COLUMNS = ("first_frame", "length", "n_samples", "n_points", "mean_range", "predicted_confidence", "updated_at")


class Track(Base):
    """A chain of segments. `keep_start..keep_end` is the kept frame range after truncation."""

    __tablename__ = "tracks"
    __table_args__ = (
        UniqueConstraint("sequence_id", "key"),
        CheckConstraint(_in("status", TRACK_STATUSES), name="status"),
        CheckConstraint(_in("label_source", LABEL_SOURCES), name="label_source"),
        # the review queue's order (priority, then id, both descending: crud.review_queue), read
        # off the index without sorting the ties, in one sequence or over all (migration 0011)
        Index("ix_tracks_queue_priority", "sequence_id", "status", "priority", "id"),
        Index("ix_tracks_status_priority", "status", "priority", "id"),
        # review/next looks for the caller's own running lease first (it scanned every track);
        # partial: a plain index of a mostly-NULL column looks useless to SQLite's statistics
        Index("ix_tracks_lease_user_id", "lease_user_id", sqlite_where=text("lease_user_id IS NOT NULL"),
              postgresql_where=text("lease_user_id IS NOT NULL")),
        Index("ix_tracks_predicted", "predicted_class", "predicted_confidence"),
        # predicted class + confidence, then every sort key of GET /tracks but updated_at (which each
        # action changes): a filtered, sorted page is found in the index alone (crud.list_tracks)
        Index(
            "ix_tracks_predicted_sorts", "predicted_class", "predicted_confidence", "length", "n_samples",
            "mean_range", "n_points", "first_frame",
        ),
        # one index per sort key of GET /tracks, with the id that breaks ties: a page is read off
        # the index in either direction (SQLite's indexes hold the rowid anyway; PostgreSQL's
        # don't, and sorted every row of a long run of equal lengths without it)
        *(Index(f"ix_tracks_sort_{c}", c, "id") for c in TRACK_SORT_COLUMNS),
        # ids are never reused on SQLite either (migration 0010): an edit sent with the id of a
        # track that an undo removed must get 404, never land on a newer track
        {"sqlite_autoincrement": True},
    )

    id: Mapped[int] = mapped_column(BigId, primary_key=True)
    sequence_id: Mapped[int] = mapped_column(ForeignKey("sequences.id", ondelete="CASCADE"))
    key: Mapped[int] = mapped_column(BigInteger)  # the pipeline's track id (>= 1, per sequence)
    status: Mapped[str] = mapped_column(String(16), default="pending")
    first_frame: Mapped[int] = mapped_column(Integer)
    last_frame: Mapped[int] = mapped_column(Integer)
    keep_start: Mapped[int] = mapped_column(Integer)
    keep_end: Mapped[int] = mapped_column(Integer)
    length: Mapped[int] = mapped_column(Integer)  # frames with a segment in the kept range
    n_samples: Mapped[int] = mapped_column(Integer, default=0)  # valid samples in the kept range
    n_points: Mapped[int] = mapped_column(Integer, default=0)
    mean_range: Mapped[float] = mapped_column(Float, default=0.0)
    label: Mapped[str | None] = mapped_column(String(16), index=True)
    predicted_class: Mapped[str | None] = mapped_column(String(16))  # ix_tracks_predicted(_sorts)
    predicted_confidence: Mapped[float | None] = mapped_column(Float)
    # migration 0011: the review queue serves the highest first: the points the track's review is
    # expected to correct (n_points x (1 - predicted confidence)), n_points before any prediction
    priority: Mapped[float] = mapped_column(Float, default=0.0, server_default="0")
    label_source: Mapped[str | None] = mapped_column(String(16))  # LABEL_SOURCES; None unless accepted with a class
    version: Mapped[int] = mapped_column(Integer, default=1)
    updated_at: Mapped[datetime] = mapped_column(DateTime, default=utcnow)
    reviewed_by_id: Mapped[int | None] = mapped_column(ForeignKey("users.id", ondelete="SET NULL"))
    lease_user_id: Mapped[int | None] = mapped_column(ForeignKey("users.id", ondelete="SET NULL"))
    lease_expires_at: Mapped[datetime | None] = mapped_column(DateTime)


class Assignment(Base):
    """An operator (or reviewer) assigned to a sequence by an admin: they may queue jobs on it
    (app/jobs/policy.py). Leases and reviews alone give no such right. Migration 0010."""

    __tablename__ = "assignments"
    __table_args__ = (UniqueConstraint("sequence_id", "user_id"),)

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    sequence_id: Mapped[int] = mapped_column(ForeignKey("sequences.id", ondelete="CASCADE"))
    user_id: Mapped[int] = mapped_column(ForeignKey("users.id", ondelete="CASCADE"), index=True)
    created_by_id: Mapped[int | None] = mapped_column(ForeignKey("users.id", ondelete="SET NULL"))
    created_at: Mapped[datetime] = mapped_column(DateTime, default=utcnow)


class Segment(Base):
    """One segment of one frame; `sample_index` indexes the frame artifact's samples (None = no sample)."""

    __tablename__ = "segments"
    __table_args__ = (
        UniqueConstraint("frame_id", "local_id"),
        Index("ix_segments_track_frame", "track_id", "frame_index"),
    )

    id: Mapped[int] = mapped_column(BigId, primary_key=True)
    sequence_id: Mapped[int] = mapped_column(ForeignKey("sequences.id", ondelete="CASCADE"), index=True)
    frame_id: Mapped[int] = mapped_column(ForeignKey("frames.id", ondelete="CASCADE"))
    frame_index: Mapped[int] = mapped_column(Integer)
    local_id: Mapped[int] = mapped_column(Integer)
    track_id: Mapped[int | None] = mapped_column(ForeignKey("tracks.id", ondelete="CASCADE"))
    n_points: Mapped[int] = mapped_column(Integer)
    cx: Mapped[float] = mapped_column(Float)  # centroid, lidar frame
    cy: Mapped[float] = mapped_column(Float)
    cz: Mapped[float] = mapped_column(Float)
    wx: Mapped[float] = mapped_column(Float)  # centroid, world frame
    wy: Mapped[float] = mapped_column(Float)
    wz: Mapped[float] = mapped_column(Float)
    range: Mapped[float] = mapped_column(Float)
    valid: Mapped[bool] = mapped_column(Boolean)
    link_score: Mapped[float | None] = mapped_column(Float)  # link to the previous frame; None = track start
    sample_index: Mapped[int | None] = mapped_column(Integer)


class Stitch(Base):
    """Two tracks joined by the association's fragment links: pieces of one object that split,
    merged or reshuffled between frames (`pipeline.association.Links.fragments`). An operator
    confirms (one object) or rejects it; the fragment pairs of a confirmed stitch between two
    accepted tracks are verified constraints. track_a_id < track_b_id."""

    __tablename__ = "stitches"
    __table_args__ = (
        UniqueConstraint("track_a_id", "track_b_id"),
        CheckConstraint(_in("status", ("pending", "confirmed", "rejected")), name="status"),
        Index("ix_stitches_sequence_id_status", "sequence_id", "status"),
    )

    id: Mapped[int] = mapped_column(BigId, primary_key=True)
    sequence_id: Mapped[int] = mapped_column(ForeignKey("sequences.id", ondelete="CASCADE"), index=True)
    track_a_id: Mapped[int] = mapped_column(ForeignKey("tracks.id", ondelete="CASCADE"), index=True)
    track_b_id: Mapped[int] = mapped_column(ForeignKey("tracks.id", ondelete="CASCADE"), index=True)
    links: Mapped[int] = mapped_column(Integer, default=0)  # fragment pairs joining the two tracks
    share: Mapped[float] = mapped_column(Float, default=0.0)  # their largest shared-point share
    status: Mapped[str] = mapped_column(String(16), default="pending")
    version: Mapped[int] = mapped_column(Integer, default=1)
    decided_by_id: Mapped[int | None] = mapped_column(ForeignKey("users.id", ondelete="SET NULL"))
    decided_at: Mapped[datetime | None] = mapped_column(DateTime)


class PairConstraint(Base):
    """A must-link pair of samples: consecutive valid samples of one track (kind `must_link`), or
    a fragment link between two tracks of a stitch (kind `fragment`, `stitch_id` set; segment_a is
    in `track_id` at frame t, segment_b in the other track at t-1), with its score."""

    __tablename__ = "constraints"

    id: Mapped[int] = mapped_column(BigId, primary_key=True)
    sequence_id: Mapped[int] = mapped_column(ForeignKey("sequences.id", ondelete="CASCADE"), index=True)
    track_id: Mapped[int] = mapped_column(ForeignKey("tracks.id", ondelete="CASCADE"), index=True)
    segment_a_id: Mapped[int] = mapped_column(ForeignKey("segments.id", ondelete="CASCADE"))
    segment_b_id: Mapped[int] = mapped_column(ForeignKey("segments.id", ondelete="CASCADE"))
    score: Mapped[float] = mapped_column(Float)
    kind: Mapped[str] = mapped_column(String(16), default="must_link")
    # migration 0007: the stitch of a fragment pair
    stitch_id: Mapped[int | None] = mapped_column(ForeignKey("stitches.id", ondelete="CASCADE"), index=True)


class Label(Base):
    """A labelled sample, materialised from its track's decision (accepted, labelled, in the kept range)."""

    __tablename__ = "labels"

    id: Mapped[int] = mapped_column(BigId, primary_key=True)
    sequence_id: Mapped[int] = mapped_column(ForeignKey("sequences.id", ondelete="CASCADE"), index=True)
    segment_id: Mapped[int] = mapped_column(ForeignKey("segments.id", ondelete="CASCADE"), unique=True)
    track_id: Mapped[int] = mapped_column(ForeignKey("tracks.id", ondelete="CASCADE"), index=True)
    class_name: Mapped[str] = mapped_column(String(16))
    class_index: Mapped[int] = mapped_column(Integer)
    source: Mapped[str] = mapped_column(String(16), default="review")  # LABEL_SOURCES (migration 0011; "track" before)
    user_id: Mapped[int | None] = mapped_column(ForeignKey("users.id", ondelete="SET NULL"))
    created_at: Mapped[datetime] = mapped_column(DateTime, default=utcnow)


class AnnotationEvent(Base):
    """Append-only log of track actions; `after` of the last event per track is its review state."""

    __tablename__ = "annotation_events"
    __table_args__ = (
        CheckConstraint(_in("action", ACTIONS), name="action"),
        Index("ix_annotation_events_track_id_id", "track_id", "id"),
    )

    id: Mapped[int] = mapped_column(BigId, primary_key=True)
    track_id: Mapped[int] = mapped_column(ForeignKey("tracks.id", ondelete="CASCADE"))
    user_id: Mapped[int | None] = mapped_column(ForeignKey("users.id", ondelete="SET NULL"), index=True)
    action: Mapped[str] = mapped_column(String(16))
    created_at: Mapped[datetime] = mapped_column(DateTime, default=utcnow)
    version_before: Mapped[int] = mapped_column(Integer)
    version_after: Mapped[int] = mapped_column(Integer)
    before: Mapped[dict[str, Any]] = mapped_column(JSON)
    after: Mapped[dict[str, Any]] = mapped_column(JSON)
    reverts_event_id: Mapped[int | None] = mapped_column(ForeignKey("annotation_events.id", ondelete="SET NULL"))
    # migration 0009: what a split or merge changed beyond the review state (frames' artifact
    # files before and after, segment rows, constraint rows, the other track), so that undo
    # restores it exactly and the log can be replayed (app/services/repair.py)
    detail: Mapped[dict[str, Any] | None] = mapped_column(JSON)


class Job(Base):
    __tablename__ = "jobs"
    __table_args__ = (
        CheckConstraint(_in("status", JOB_STATUSES), name="status"),
        Index("ix_jobs_status_id", "status", "id"),
        Index("ix_jobs_status_priority_id", "status", "priority", "id"),
    )

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    type: Mapped[str] = mapped_column(String(32))
    params: Mapped[dict[str, Any]] = mapped_column(JSON, default=dict)
    status: Mapped[str] = mapped_column(String(16), default="queued")
    progress: Mapped[float] = mapped_column(Float, default=0.0)
    message: Mapped[str] = mapped_column(Text, default="")
    result: Mapped[dict[str, Any] | None] = mapped_column(JSON)
    error: Mapped[str | None] = mapped_column(Text)
    created_by_id: Mapped[int | None] = mapped_column(ForeignKey("users.id", ondelete="SET NULL"), index=True)
    created_at: Mapped[datetime] = mapped_column(DateTime, default=utcnow)
    started_at: Mapped[datetime | None] = mapped_column(DateTime)
    finished_at: Mapped[datetime | None] = mapped_column(DateTime)
    heartbeat_at: Mapped[datetime | None] = mapped_column(DateTime)
    lease_expires_at: Mapped[datetime | None] = mapped_column(DateTime)
    worker_id: Mapped[str | None] = mapped_column(String(128))
    attempts: Mapped[int] = mapped_column(Integer, default=0)
    cancel_requested: Mapped[bool] = mapped_column(Boolean, default=False)
    # migration 0008: higher runs first (admins' jobs, app.jobs.policy)
    priority: Mapped[int] = mapped_column(Integer, default=0, server_default="0")


class ModelVersion(Base):
    """A trained model: the checkpoint path (it carries model + pipeline config) and its metrics."""

    __tablename__ = "model_versions"

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    name: Mapped[str] = mapped_column(String(128))
    kind: Mapped[str] = mapped_column(String(32))  # train | finetune
    path: Mapped[str] = mapped_column(Text)
    config: Mapped[dict[str, Any] | None] = mapped_column(JSON)
    metrics: Mapped[dict[str, Any] | None] = mapped_column(JSON)
    parent_id: Mapped[int | None] = mapped_column(ForeignKey("model_versions.id", ondelete="SET NULL"))
    job_id: Mapped[int | None] = mapped_column(ForeignKey("jobs.id", ondelete="SET NULL"))
    created_by_id: Mapped[int | None] = mapped_column(ForeignKey("users.id", ondelete="SET NULL"))
    created_at: Mapped[datetime] = mapped_column(DateTime, default=utcnow)


class AnchorProposal(Base):
    """A sample (`level` sample: `segment_id`) or a whole track (`level` track) proposed as a
    fine-tuning anchor; the operator confirms it (answer_class = proposed_class), corrects it
    (another answer_class) or rejects it. See app/jobs/anchors.py."""

    __tablename__ = "anchor_proposals"
    __table_args__ = (
        CheckConstraint(_in("status", ("proposed", "confirmed", "rejected")), name="status"),
        CheckConstraint(_in("level", ANCHOR_LEVELS), name="level"),
        Index("ix_anchor_proposals_sequence_id_status", "sequence_id", "status"),
        # ids are never reused on SQLite either: an answer to a replaced proposal must get 404,
        # never land on a newer proposal that took its id
        {"sqlite_autoincrement": True},
    )

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    sequence_id: Mapped[int] = mapped_column(ForeignKey("sequences.id", ondelete="CASCADE"), index=True)
    track_id: Mapped[int] = mapped_column(ForeignKey("tracks.id", ondelete="CASCADE"), index=True)
    model_version_id: Mapped[int | None] = mapped_column(ForeignKey("model_versions.id", ondelete="SET NULL"))
    proposed_class: Mapped[str | None] = mapped_column(String(16))
    score: Mapped[float] = mapped_column(Float)
    status: Mapped[str] = mapped_column(String(16), default="proposed")
    decided_by_id: Mapped[int | None] = mapped_column(ForeignKey("users.id", ondelete="SET NULL"))
    created_at: Mapped[datetime] = mapped_column(DateTime, default=utcnow)
    # migration 0003: sample-level proposals, the strategy, the answer
    segment_id: Mapped[int | None] = mapped_column(ForeignKey("segments.id", ondelete="CASCADE"), index=True)
    level: Mapped[str] = mapped_column(String(8), default="track", server_default="track")
    strategy: Mapped[str | None] = mapped_column(String(16))
    rank: Mapped[int | None] = mapped_column(Integer)  # order within its class (0 = first proposed)
    answer_class: Mapped[str | None] = mapped_column(String(16))
    decided_at: Mapped[datetime | None] = mapped_column(DateTime)
    job_id: Mapped[int | None] = mapped_column(ForeignKey("jobs.id", ondelete="SET NULL"))


class AnchorEvent(Base):
    """Append-only log of anchor answers: who confirmed, corrected or rejected which proposal."""

    __tablename__ = "anchor_events"
    __table_args__ = (CheckConstraint(_in("action", ANCHOR_ACTIONS), name="action"),)

    id: Mapped[int] = mapped_column(BigId, primary_key=True)
    proposal_id: Mapped[int] = mapped_column(ForeignKey("anchor_proposals.id", ondelete="CASCADE"), index=True)
    sequence_id: Mapped[int] = mapped_column(ForeignKey("sequences.id", ondelete="CASCADE"), index=True)
    user_id: Mapped[int | None] = mapped_column(ForeignKey("users.id", ondelete="SET NULL"), index=True)
    action: Mapped[str] = mapped_column(String(16))
    class_name: Mapped[str | None] = mapped_column(String(16))
    created_at: Mapped[datetime] = mapped_column(DateTime, default=utcnow)


AUDIT_STATUSES = ("queued", "agreed", "corrected")


class Audit(Base):
    """An accepted track sampled for a second look (the quality stage): the operator who accepted
    it and the class they gave, then the auditor's verdict: agreed, or corrected to `answer_label`
    (the correction is applied to the track as a `label` action). Migration 0008."""

    __tablename__ = "audits"
    __table_args__ = (
        CheckConstraint(_in("status", AUDIT_STATUSES), name="status"),
        Index("ix_audits_sequence_id_status", "sequence_id", "status"),
    )

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    sequence_id: Mapped[int] = mapped_column(ForeignKey("sequences.id", ondelete="CASCADE"))
    track_id: Mapped[int] = mapped_column(ForeignKey("tracks.id", ondelete="CASCADE"), index=True)
    operator_id: Mapped[int | None] = mapped_column(ForeignKey("users.id", ondelete="SET NULL"), index=True)
    label: Mapped[str | None] = mapped_column(String(16))  # the operator's class when sampled
    status: Mapped[str] = mapped_column(String(16), default="queued")
    sampled_by_id: Mapped[int | None] = mapped_column(ForeignKey("users.id", ondelete="SET NULL"))
    created_at: Mapped[datetime] = mapped_column(DateTime, default=utcnow)
    auditor_id: Mapped[int | None] = mapped_column(ForeignKey("users.id", ondelete="SET NULL"))
    answer_label: Mapped[str | None] = mapped_column(String(16))
    decided_at: Mapped[datetime | None] = mapped_column(DateTime)
    # migration 0011: the label's source when sampled (LABEL_SOURCES), so bulk accepts are audited
    # apart, and the bulk accept that gave it (an undone bulk's audits leave its estimate)
    source: Mapped[str | None] = mapped_column(String(16))
    bulk_id: Mapped[int | None] = mapped_column(ForeignKey("bulk_actions.id", ondelete="SET NULL"))


class BulkAction(Base):
    """One bulk accept: every pending track of a sequence predicted as `class_name` with a
    confidence of at least `min_confidence` accepted with that class in one operator action
    (app/crud/bulk.py). Each track also gets a `bulk_accept` event naming this row in its
    detail; `undone_at` is set when the whole bulk is undone."""

    __tablename__ = "bulk_actions"
    __table_args__ = (Index("ix_bulk_actions_sequence_id_id", "sequence_id", "id"),)

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    sequence_id: Mapped[int] = mapped_column(ForeignKey("sequences.id", ondelete="CASCADE"))
    user_id: Mapped[int | None] = mapped_column(ForeignKey("users.id", ondelete="SET NULL"))
    class_name: Mapped[str] = mapped_column(String(16))
    min_confidence: Mapped[float] = mapped_column(Float)
    n_tracks: Mapped[int] = mapped_column(Integer)
    n_points: Mapped[int] = mapped_column(BigInteger)
    created_at: Mapped[datetime] = mapped_column(DateTime, default=utcnow)
    undone_at: Mapped[datetime | None] = mapped_column(DateTime)
    undone_by_id: Mapped[int | None] = mapped_column(ForeignKey("users.id", ondelete="SET NULL"))


class GroundRegion(Base):
    """A polygon an operator drew on the top view of a sequence (world x, y) and a class of its
    label set: the ground points of every frame inside it take that class in the exports, or with
    a height range every point inside the prism (`pipeline.propagation.GroundRegion`). Later
    regions are drawn over earlier ones. Deleting one is its undo: the row stays with
    `deleted_at` set, so that the operations a sequence took can be counted
    (`crud.operation_count`). With `frame_index` it labels that frame's points only; with
    `clip_from_world` as well, `polygon` is a lasso in that camera's normalised device coordinates
    (a frame's view) and every point of the frame it holds takes the class. Migrations 0014,
    0015 (the heights), 0016 (the frame and view)."""

    __tablename__ = "ground_regions"
    __table_args__ = (Index("ix_ground_regions_sequence_id_id", "sequence_id", "id"),)

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    sequence_id: Mapped[int] = mapped_column(ForeignKey("sequences.id", ondelete="CASCADE"))
    class_name: Mapped[str] = mapped_column(String(32))
    polygon: Mapped[list[list[float]]] = mapped_column(JSON)  # [[x, y], ...] world metres, not closed
    z_min: Mapped[float | None] = mapped_column(Float)  # world z (m): with z_max, every point between (0015)
    z_max: Mapped[float | None] = mapped_column(Float)
    frame_index: Mapped[int | None] = mapped_column(Integer)  # the one frame it labels (0016)
    clip_from_world: Mapped[list[float] | None] = mapped_column(JSON)  # 16 floats, row-major: a view's lasso
    created_by_id: Mapped[int | None] = mapped_column(ForeignKey("users.id", ondelete="SET NULL"))
    created_at: Mapped[datetime] = mapped_column(DateTime, default=utcnow)
    deleted_at: Mapped[datetime | None] = mapped_column(DateTime)
    deleted_by_id: Mapped[int | None] = mapped_column(ForeignKey("users.id", ondelete="SET NULL"))

    @property
    def heights(self) -> tuple[float, float] | None:
        return None if self.z_min is None or self.z_max is None else (self.z_min, self.z_max)
