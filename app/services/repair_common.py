"""What the track repairs (app/services/repair.py) share: their context, the row helpers of the write
step, and the locks.

Every repair runs in two steps. The slow part (reading frames, cutting segments, rendering
samples, writing the new artifact files) runs with no write lock and no row lock held; the write
step then locks its rows, checks that nothing it read has changed, and writes in one short
transaction. Locks are always taken in one order, so two repairs never wait on each other in a
cycle: tracks by id, then frames by id (PostgreSQL: `FOR NO KEY UPDATE`, which leaves other
writers' foreign-key checks alone). A frame's artifact file name is the version of its segments:
a split, merge or undo that touches a frame gives it a new one, so a write step that finds a
frame's file changed since its read step starts again (`app.core.errors.Retry`).
"""

from __future__ import annotations

import secrets
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np
from sqlalchemy import case, cast, delete, func, insert, literal, null, select
from sqlalchemy.orm import Session

from app import crud
from app.artifacts import ArtifactStore, FrameArtifact
from app.core.errors import Conflict, NotFound, Retry, check_version
from app.crud import AuthUser
from app.models import AnnotationEvent, Frame, PairConstraint, Segment, Track, utcnow

SEGMENT_FIELDS = ("track_id", "n_points", "cx", "cy", "cz", "wx", "wy", "wz", "range", "valid", "link_score", "sample_index")
TRACK_FIELDS = (
    "status", "label", "first_frame", "last_frame", "keep_start", "keep_end", "length", "n_samples", "n_points", "mean_range",
    "priority", "label_source",
)


class Guard(Protocol):
    """The caller and their lease rights (app.api.deps.LeaseGuard)."""

    user: AuthUser

    def check(self, session: Session, track: Track, renew: bool = True) -> None: ...


@dataclass(frozen=True)
class RepairContext:
    """What a repair needs besides the database: the artifact files, the sequence's pipeline
    config and its sensor as ingest recorded it (`pipeline.resample` re-renders the samples)."""

    artifacts: ArtifactStore
    config: Any
    sensor: dict[str, Any] | None

    def sensor_model(self) -> Any:
        """The sequence's `pipeline.sensors.SensorModel`; Conflict when ingest recorded none."""
        from pipeline.sensors import SensorModel

        if self.sensor is None:
            raise Conflict("the sequence has no sensor model recorded (ingested before sensors were stored); "
                           "ingest it again")
        return SensorModel.from_dict(self.sensor)


# ----------------------------------------------------------------------------- reading


def read_track(session: Session, track_id: int, version: int) -> Track:
    """The track (unlocked) of a ready sequence at `version`: NotFound, Conflict otherwise."""
    track = session.get(Track, track_id)
    if track is None:
        raise NotFound(f"track {track_id} not found")
    crud.require_ready(session, track.sequence_id, "tracks can be changed once it is ready")
    check_version("track", track_id, version, track.version)
    return track


def pose_of(frame: Frame) -> np.ndarray:
    return np.eye(4) if frame.pose is None else np.asarray(frame.pose, np.float64).reshape(4, 4)


def write_revision(ctx: RepairContext, frame: Frame, art: FrameArtifact) -> str:
    """The frame's arrays under a new file name (the old file stays, for undo)."""
    return ctx.artifacts.write_frame(frame.sequence_id, frame.index, art, revision=secrets.token_hex(6))


def remove_files(ctx: RepairContext, rels: list[str]) -> None:
    """Files a repair wrote and then did not commit."""
    for rel in rels:
        ctx.artifacts.path(rel).unlink(missing_ok=True)


# ----------------------------------------------------------------------------- locking


def lock_tracks(session: Session, versions: dict[int, int], guard: Guard) -> dict[int, Track]:
    """The tracks locked in id order, each at its expected version, of a ready sequence, and
    free for the caller (lease; 409 naming the holder otherwise)."""
    rows = session.scalars(
        select(Track).where(Track.id.in_(sorted(versions))).order_by(Track.id).with_for_update(key_share=True)
        .execution_options(populate_existing=True)
    ).all()
    tracks = {t.id: t for t in rows}
    for track_id in sorted(versions):
        track = tracks.get(track_id)
        if track is None:
            raise NotFound(f"track {track_id} not found")
        guard.check(session, track)
        check_version("track", track_id, versions[track_id], track.version)
    for track in rows:
        crud.require_ready(session, track.sequence_id, "tracks can be changed once it is ready")
    return tracks


def lock_frames(session: Session, expected: dict[int, str]) -> None:
    """Lock the frames in id order; Retry when one's artifact is no longer the one the slow step
    read (another repair rewrote the frame meanwhile)."""
    if not expected:
        return
    rows = session.execute(
        select(Frame.id, Frame.artifact).where(Frame.id.in_(sorted(expected))).order_by(Frame.id)
        .with_for_update(key_share=True)
    ).all()
    current = {int(r.id): r.artifact for r in rows}
    if current != expected:
        raise Retry("a frame of this repair changed since it was read")


# ----------------------------------------------------------------------------- writing


def track_fields(track: Track) -> dict[str, Any]:
    return {f: getattr(track, f) for f in TRACK_FIELDS}


def link_rows(session: Session, track_ids: list[int]) -> list[dict[str, Any]]:
    """The tracks' own must-link constraint rows (what a split or merge rebuilds)."""
    rows = session.execute(
        select(PairConstraint.id, PairConstraint.sequence_id, PairConstraint.track_id, PairConstraint.segment_a_id,
               PairConstraint.segment_b_id, PairConstraint.score)
        .where(PairConstraint.track_id.in_(track_ids), PairConstraint.kind == "must_link")
        .order_by(PairConstraint.id)
    ).mappings().all()
    return [dict(r) for r in rows]


def rebuild_links(session: Session, track: Track) -> None:
    """The track's must-link pairs as ingest makes them (`pipeline.links`): its members are its
    valid segments with a sample, in frame order, each pair scored by the later member's link score."""
    from pipeline.links import LinkBuilder

    session.execute(delete(PairConstraint).where(PairConstraint.track_id == track.id, PairConstraint.kind == "must_link"))
    segs = session.execute(
        select(Segment.id, Segment.link_score)
        .where(Segment.track_id == track.id, Segment.valid.is_(True), Segment.sample_index.is_not(None))
        .order_by(Segment.frame_index, Segment.id)
    ).all()
    score = {int(r.id): float(r.link_score or 0.0) for r in segs}
    rows = [
        {"sequence_id": track.sequence_id, "track_id": track.id, "segment_a_id": a, "segment_b_id": b,
         "score": score[b], "kind": "must_link"}
        for a, b in LinkBuilder().chain(track.id, [int(r.id) for r in segs]).tolist()
    ]
    if rows:  # the table, not the entity: the ORM's bulk insert took 5 ms for 70 rows
        session.execute(insert(PairConstraint.__table__), rows)


def restore_links(session: Session, track_ids: list[int], rows: list[dict[str, Any]]) -> None:
    """The tracks' must-link rows exactly as recorded (same ids)."""
    session.execute(delete(PairConstraint).where(PairConstraint.track_id.in_(track_ids), PairConstraint.kind == "must_link"))
    if rows:
        session.execute(insert(PairConstraint.__table__), [{**r, "kind": "must_link"} for r in rows])


def restat(session: Session, track: Track, ranges_from_segments: bool) -> None:
    """Length (frames), samples, points and range in the kept range, from the segment rows, as a
    truncation counts them (the operator's point count is the kept frames'); with
    `ranges_from_segments` the frame range and kept range become the segments' own."""
    if ranges_from_segments:
        lo, hi = session.execute(
            select(func.min(Segment.frame_index), func.max(Segment.frame_index)).where(Segment.track_id == track.id)
        ).one()
        track.first_frame = track.keep_start = int(lo)
        track.last_frame = track.keep_end = int(hi)
    kept = [Segment.track_id == track.id, Segment.frame_index.between(track.keep_start, track.keep_end)]
    length, n_samples, mean_range = session.execute(
        select(func.count(func.distinct(Segment.frame_index)), func.count(Segment.sample_index), func.avg(Segment.range))
        .where(*kept)
    ).one()
    track.length, track.n_samples, track.mean_range = int(length), int(n_samples), float(mean_range or 0.0)
    track.n_points = int(session.scalar(select(func.coalesce(func.sum(Segment.n_points), 0)).where(*kept)))
    track.priority = crud.queue_priority(track.n_points, track.predicted_confidence)


def add_event(
    session: Session, track: Track, user: AuthUser, action: str, version: int, before: dict[str, Any],
    detail: dict[str, Any] | None, reverts_event_id: int | None = None,
) -> AnnotationEvent:
    ev = AnnotationEvent(
        track_id=track.id, user_id=user.id, action=action, created_at=utcnow(), version_before=version,
        version_after=version + 1, before=before, after=crud.review_state(track), detail=detail,
        reverts_event_id=reverts_event_id,
    )
    track.version = version + 1
    track.updated_at = ev.created_at
    track.reviewed_by_id = user.id
    session.add(ev)
    session.flush()
    return ev


def restore_frames(session: Session, frames: list[dict[str, Any]]) -> None:
    """Each frame's artifact and counts as the event recorded them before the repair."""
    update_by_id(session, Frame.__table__, [{"id": f["frame_id"], "artifact": f["artifact_before"],
                                             "n_segments": f["n_segments"], "n_samples": f["n_samples"]} for f in frames])


def refresh_labels(session: Session, user: AuthUser, *tracks: Track) -> None:
    session.flush()
    for t in tracks:
        crud.refresh_labels(session, t, user.id, crud.existing_label_set(session, t.sequence_id))


def update_by_id(session: Session, table: Any, rows: list[dict[str, Any]]) -> None:
    """Set fields of rows by id (`rows`: {"id": ..., field: value, ...}, each with the same
    fields) in one `UPDATE ... SET f = CASE id WHEN ... END` per 500 rows. An executemany runs a
    statement per row, and on SQLite each hands the GIL over and back: under load the write
    transaction, which holds the write lock, stretched from 20 to 180 ms. A NULL is cast to its
    column's type: PostgreSQL types a CASE whose branches are all untyped NULLs as text."""
    if not rows:
        return
    fields = [k for k in rows[0] if k != "id"]
    for k in range(0, len(rows), 500):
        chunk = rows[k : k + 500]
        values = {f: case({r["id"]: _typed(r[f], table.c[f].type) for r in chunk}, value=table.c.id) for f in fields}
        session.execute(table.update().where(table.c.id.in_([r["id"] for r in chunk])).values(values))


def _typed(value: Any, type_: Any) -> Any:
    return cast(null(), type_) if value is None else literal(value, type_)


def update_segments(session: Session, rows: list[dict[str, Any]]) -> None:
    """Set the given fields of segment rows by id (see `update_by_id`)."""
    update_by_id(session, Segment.__table__, rows)
