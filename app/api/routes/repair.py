"""Track repair (issue 22): split a track by a region, merge two tracks, undo either (or any
other action). Each takes the versions the operator saw: 404 unknown track, 409 stale version,
sequence not ready, merged track, or a refused lease; 422 bad body or a region that selects no
point or every point. Changes are events in the track's log (`GET /tracks/{id}/events`)."""

from __future__ import annotations

import numpy as np
from fastapi import APIRouter
from sqlalchemy.orm import Session

from app import repair
from app.api.deps import ArtifactsDep, BigIdPath, LeaseGuard, LeaseGuardDep, SettingsDep, WriteSessionDep
from app.core.config import Settings
from app.core.errors import NotFound
from app.models import Track
from app.schemas import MergeAction, SplitAction, SplitPublic, TrackPublic, UndoAction

router = APIRouter(tags=["tracks"])
RESPONSES: dict[int | str, dict[str, str]] = {
    404: {"description": "No such track."},
    409: {"description": "Stale version, sequence not ready, track merged away, or the caller may not change the track now (lease)."},
    422: {"description": "Invalid body, or a region that selects no point or every point of the track."},
}


def _check_lease(session: Session, track_ids: list[int], guard: LeaseGuard) -> None:
    """Refuse the change when another user holds the lease of one of these tracks (409 naming
    the holder, app.leases), unless an admin overrides; renews the caller's own leases."""
    for track_id in track_ids:
        track = session.get(Track, track_id, with_for_update=True)
        if track is not None:
            guard.check(session, track)


def _context(session: Session, settings: Settings, artifacts: ArtifactsDep, track_id: int) -> repair.RepairContext:
    track = session.get(Track, track_id)
    if track is None:
        raise NotFound(f"track {track_id} not found")
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
    artifacts: ArtifactsDep,
) -> SplitPublic:
    """Cut the track's points inside `region` (world frame) out into a new pending track, in every
    kept frame or in `frame_index` only: a box, a half-space, a top-view prism, a screen lasso, the
    points above a height, or (`predicted`) the whole segments a model classifies as a class. Cut
    segments get new samples; both tracks get new versions."""
    _check_lease(session, [track_id], guard)
    ctx = _context(session, settings, artifacts, track_id)
    selector = _selector(session, ctx, track_id, body)
    res = repair.split_track(session, ctx, track_id, guard.user, body.version, selector, body.frame_index)
    return SplitPublic(track=TrackPublic.model_validate(res.track), new_track=TrackPublic.model_validate(res.new_track),
                       moved_points=res.moved_points)


@router.post("/tracks/{track_id}/merge", responses=RESPONSES)
def merge_tracks(
    track_id: BigIdPath, body: MergeAction, guard: LeaseGuardDep, session: WriteSessionDep, settings: SettingsDep,
    artifacts: ArtifactsDep,
) -> TrackPublic:
    """Join `other_track_id` into this track (one object in two tracks, e.g. both sides of a
    stitch). The other track becomes `merged`; the joined track keeps the review state both
    shared, else it is pending without a class."""
    _check_lease(session, [track_id, body.other_track_id], guard)
    ctx = _context(session, settings, artifacts, track_id)
    track = repair.merge_tracks(session, ctx, track_id, guard.user, body.version, body.other_track_id, body.other_version)
    return TrackPublic.model_validate(track)


@router.post("/tracks/{track_id}/undo", responses=RESPONSES)
def undo_track(
    track_id: BigIdPath, body: UndoAction, guard: LeaseGuardDep, session: WriteSessionDep, settings: SettingsDep,
    artifacts: ArtifactsDep,
) -> TrackPublic:
    """Revert the caller's last not-yet-undone action on this track, a split or merge included
    (409 `nothing to undo` when there is none)."""
    _check_lease(session, [track_id], guard)
    ctx = _context(session, settings, artifacts, track_id)
    return TrackPublic.model_validate(repair.undo(session, ctx, track_id, guard.user, body.version, guard.override))
