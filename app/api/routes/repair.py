"""Track repair (issue 22): split a track by a region, merge two tracks, undo either (or any
other action). Each takes the versions the operator saw: 404 unknown track, 409 stale version,
sequence not ready, merged track, a refused lease, a region that selects no point or every point,
or a track merged with itself; 422 a body the schema refuses. Changes are events in the track's log (`GET /tracks/{id}/events`).

A split or merge does its slow part (cutting frames, rendering samples, writing files) in a read
session and writes in one short transaction (app/services/repair.py): other operators' actions never wait
behind it. Races with other writers run the request again (app/api/retry.py), never a 500."""

from __future__ import annotations

import time

import numpy as np
from fastapi import APIRouter, Response
from sqlalchemy.orm import Session

from app import crud
from app.api.deps import ArtifactsDep, BigIdPath, DatabaseDep, LeaseGuardDep, SettingsDep, WriteSessionDep
from app.core.config import Settings
from app.crud import track_ids
from app.schemas import MergeAction, SplitAction, SplitPublic, TrackPublic, UndoAction
from app.services import repair

router = APIRouter(tags=["tracks"])
RESPONSES: dict[int | str, dict[str, str]] = {
    404: {"description": "No such track."},
    409: {"description": "Stale version, sequence not ready, track merged away, the caller may not change the "
                         "track now (lease), or a region that selects no point or every point of the track."},
    422: {"description": "A body the schema refuses."},
}


def _write_begun(session: Session) -> float:
    """Begin the write transaction (SQLite: wait for the write lock here) and return the time:
    what follows is how long the lock is held, not how long it was waited for."""
    session.connection()
    return time.perf_counter()


def _write_timing(response: Response, t0: float) -> None:
    """`Server-Timing: write;dur=<ms>`: how long the write transaction held its locks (SQLite's
    write lock; on PostgreSQL row locks, from BEGIN on)."""
    response.headers["Server-Timing"] = f"write;dur={1e3 * (time.perf_counter() - t0):.2f}"


def _context(session: Session, settings: Settings, artifacts: ArtifactsDep, track_id: int) -> repair.RepairContext:
    track = crud.get_track(session, track_id)
    return repair.repair_context(session, settings, artifacts, track.sequence_id)


def _selector(session: Session, ctx: repair.RepairContext, track_id: int, body: SplitAction) -> repair.Selector:
    from pipeline import regions

    r, record = body.region, body.region.model_dump(mode="json")
    if r.kind == "predicted":
        return repair.predicted_selector(session, ctx, track_id, r.model_id, r.class_name, record)
    if r.kind == "box":
        return repair.Selector(regions.Box(np.array(r.center), np.array(r.size), np.array(r.wxyz)), record=record)
    if r.kind == "halfspace":
        return repair.Selector(regions.HalfSpace(np.array(r.normal), float(r.offset)), record=record)
    if r.kind == "prism":
        return repair.Selector(regions.Prism(np.array(r.polygon), float(r.z_min), float(r.z_max)), record=record)
    if r.kind == "lasso":
        return repair.Selector(regions.ScreenLasso(np.array(r.polygon), np.array(r.clip_from_world).reshape(4, 4)), record=record)
    return repair.Selector(min_height=float(r.min_height), record=record)


@router.post("/tracks/{track_id}/split", responses=RESPONSES)
def split_track(
    track_id: BigIdPath, body: SplitAction, guard: LeaseGuardDep, session: WriteSessionDep, settings: SettingsDep,
    artifacts: ArtifactsDep, db: DatabaseDep, response: Response,
) -> SplitPublic:
    """Cut the track's points inside `region` (world frame) out into a new pending track, in every
    kept frame or in `frame_index` only: a box, a half-space, a top-view prism, a screen lasso, the
    points above a height, or (`predicted`) the whole segments a model classifies as a class. Cut
    segments get new samples; both tracks get new versions."""
    with db.read() as read:
        ctx = _context(read, settings, artifacts, track_id)
        selector = _selector(read, ctx, track_id, body)
        plan = repair.plan_split(read, ctx, track_id, guard, body.version, selector, body.frame_index,
                                 lambda sequence_id: track_ids.reserve(db, sequence_id))
    t0 = _write_begun(session)
    res = repair.apply_split(session, plan, guard, ctx)
    _write_timing(response, t0)
    return SplitPublic(track=TrackPublic.model_validate(res.track), new_track=TrackPublic.model_validate(res.new_track),
                       moved_points=res.moved_points)


@router.post("/tracks/{track_id}/merge", responses=RESPONSES)
def merge_tracks(
    track_id: BigIdPath, body: MergeAction, guard: LeaseGuardDep, session: WriteSessionDep, settings: SettingsDep,
    artifacts: ArtifactsDep, db: DatabaseDep, response: Response,
) -> TrackPublic:
    """Join `other_track_id` into this track (one object in two tracks, e.g. both sides of a
    stitch). The other track becomes `merged`; the joined track keeps the review state both
    shared, else it is pending without a class."""
    with db.read() as read:
        ctx = _context(read, settings, artifacts, track_id)
        plan = repair.plan_merge(read, ctx, track_id, guard, body.version, body.other_track_id, body.other_version)
    t0 = _write_begun(session)
    track = repair.apply_merge(session, plan, guard, ctx)
    _write_timing(response, t0)
    return TrackPublic.model_validate(track)


@router.post("/tracks/{track_id}/undo", responses=RESPONSES)
def undo_track(track_id: BigIdPath, body: UndoAction, guard: LeaseGuardDep, session: WriteSessionDep) -> TrackPublic:
    """Revert the caller's last not-yet-undone action on this track, a split or merge included
    (409 `nothing to undo` when there is none)."""
    return TrackPublic.model_validate(repair.undo(session, track_id, guard, body.version, guard.override))
