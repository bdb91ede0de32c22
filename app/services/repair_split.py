"""Split: move the points of a track that a selector picks to a new pending track.

Per frame, a segment whose points are all selected moves whole; a cut segment keeps its row for
the points that stay and gets a new row (a new local id) for the points that go, and both parts'
statistics and samples are computed again by the pipeline (`pipeline.resample`, called
directly). The frames' artifacts are rewritten under new names. The event's `detail`
records the files before and after, the segment rows before, the rows created, the constraint
rows and the track's fields before, so that undo (app/services/repair.py) puts all of it back.

`plan_split` does the slow part with no lock held and `apply_split` writes it in one short
transaction (app/services/repair_common.py).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from sqlalchemy import func, insert, select, update
from sqlalchemy.orm import Session

from app import crud
from app.artifacts import FrameArtifact
from app.core.errors import Conflict, NotApplicable
from app.crud.track_ids import TrackIds
from app.models import Frame, Segment, Track, utcnow
from app.services.repair_common import (
    SEGMENT_FIELDS,
    Guard,
    RepairContext,
    add_event,
    link_rows,
    lock_frames,
    lock_tracks,
    pose_of,
    read_track,
    rebuild_links,
    refresh_labels,
    remove_files,
    restat,
    track_fields,
    update_by_id,
    update_segments,
    write_revision,
)

STAT_FIELDS = ("n_points", "cx", "cy", "cz", "wx", "wy", "wz", "range", "valid", "sample_index")
_ROW_COLUMNS = [Segment.id, Segment.local_id, *(getattr(Segment, f) for f in SEGMENT_FIELDS)]


@dataclass(frozen=True)
class Selector:
    """Which points of a frame go: `region` (a `pipeline.regions` region, world frame) or
    `min_height` (metres above the ground estimated again from the frame's points). `record` is
    the request that described it (JSON), kept in the event so that the split can be replayed."""

    region: Any = None
    min_height: float | None = None
    record: dict[str, Any] | None = None
    segments: dict[int, set[int]] | None = None  # frame id -> local ids of whole segments that go


@dataclass
class FramePlan:
    """One frame's part of a split: the files and counts before and after, and the segment rows
    to move (whole), to change in place (`updates`: STAT_FIELDS) and to insert."""

    frame_id: int
    index: int
    artifact_before: str
    artifact_after: str
    n_segments: int  # before the split (undo restores them)
    n_samples: int
    n_segments_after: int
    n_samples_after: int
    moved: list[int] = field(default_factory=list)
    updates: list[dict[str, Any]] = field(default_factory=list)
    inserts: list[dict[str, Any]] = field(default_factory=list)
    before: list[dict[str, Any]] = field(default_factory=list)  # full rows of every changed segment


@dataclass
class SplitPlan:
    track_id: int
    version: int
    ids: TrackIds
    frame_index: int | None
    moved_points: int
    record: dict[str, Any] | None
    frames: list[FramePlan]


@dataclass(frozen=True)
class SplitResult:
    track: Track
    new_track: Track
    moved_points: int


# ----------------------------------------------------------------------------- the slow step


def _selected_points(ctx: RepairContext, frame: Frame, art: FrameArtifact, track_id: int, selector: Selector) -> np.ndarray:
    """(N,) bool: the frame's points of the track that the selector picks."""
    from pipeline.regions import select_points

    mine = art.track == track_id
    out = np.zeros(len(art.points), bool)
    if not mine.any():
        return out
    if selector.segments is not None:
        return mine & np.isin(art.segment, sorted(selector.segments.get(frame.id, ())))
    if selector.min_height is not None:
        from pipeline import resample

        height = resample.height_above_ground(art.points, art.intensity, ctx.sensor_model(), ctx.config)
        return mine & (height >= selector.min_height)
    pose = pose_of(frame)
    world = art.points[mine].astype(np.float64) @ pose[:3, :3].T + pose[:3, 3]
    out[mine] = select_points(selector.region, world)
    return out


def _pick_frames(
    session: Session, ctx: RepairContext, track: Track, selector: Selector, frame_index: int | None
) -> list[tuple[Frame, FrameArtifact, np.ndarray]]:
    """The frames in scope with their artifact and selected points (frames with none left out)."""
    lo, hi = track.keep_start, track.keep_end
    if frame_index is not None:
        if not lo <= frame_index <= hi:
            raise NotApplicable(f"frame {frame_index} is outside the kept frames {lo}..{hi} of track {track.id}")
        lo = hi = frame_index
    frame_ids = session.scalars(
        select(Segment.frame_id).where(Segment.track_id == track.id, Segment.frame_index.between(lo, hi)).distinct()
    ).all()
    picks = []
    for frame in session.scalars(select(Frame).where(Frame.id.in_(frame_ids)).order_by(Frame.index)).all():
        art = ctx.artifacts.read_frame(frame.artifact)
        sel = _selected_points(ctx, frame, art, track.id, selector)
        if sel.any():
            picks.append((frame, art, sel))
    return picks


def _rerendered(ctx: RepairContext, art: FrameArtifact, segment: np.ndarray, ids: np.ndarray) -> tuple[Any, np.ndarray, np.ndarray]:
    """Statistics of segments `ids` after the cut, and the frame's new (samples, sample_segment).
    A re-rendered segment keeps its slot, a new one is appended, one that lost its sample gives
    its slot to the last sample: every other segment keeps its `sample_index`, so the write step
    changes a few rows per cut instead of every row after it (on PostgreSQL, one round trip each)."""
    from pipeline import resample

    res = resample.resample_segments(art.points, art.intensity, segment, ids, ctx.sensor_model(), ctx.config)
    samples, owner = list(art.samples), [int(s) for s in art.sample_segment]
    slot = {local: i for i, local in enumerate(owner)}
    for k, local in enumerate(ids.tolist()):
        j = slot.get(local)
        if res.sample_of[k] >= 0:
            if j is None:
                slot[local] = len(samples)
                samples.append(res.samples[res.sample_of[k]])
                owner.append(local)
            else:
                samples[j] = res.samples[res.sample_of[k]]
        elif j is not None:  # no sample any more: the last sample moves into its slot
            del slot[local]
            last = len(samples) - 1
            if j != last:
                samples[j], owner[j] = samples[last], owner[last]
                slot[owner[j]] = j
            samples.pop()
            owner.pop()
    shape = art.samples.shape[1:]
    stacked = np.stack(samples).astype(np.uint8) if samples else np.zeros((0, *shape), np.uint8)
    return res, stacked, np.array(owner, np.int32)


def _stats(res: Any, k: int, pose: np.ndarray, sample_index: int | None) -> dict[str, Any]:
    """STAT_FIELDS of re-rendered segment k."""
    c = res.table.centroid[k].astype(np.float64)
    w = pose[:3, :3] @ c + pose[:3, 3]
    return {
        "n_points": int(res.table.n_points[k]), "cx": float(c[0]), "cy": float(c[1]), "cz": float(c[2]),
        "wx": float(w[0]), "wy": float(w[1]), "wz": float(w[2]), "range": float(res.table.range[k]),
        "valid": bool(res.table.valid[k]), "sample_index": sample_index,
    }


def _cut(art: FrameArtifact, selected: np.ndarray, rows: dict[int, dict[str, Any]], plan: FramePlan) -> tuple[np.ndarray, list[tuple[int, int]]]:
    """The frame's new per-point segment ids and the (old local, new local) of each cut segment;
    rows that move whole go to `plan.moved`."""
    segment, next_local = art.segment.copy(), max(rows) + 1
    cuts: list[tuple[int, int]] = []
    for local in np.unique(art.segment[selected]).tolist():
        row = rows[local]
        part = selected & (art.segment == local)
        if int(part.sum()) == row["n_points"]:
            plan.moved.append(row["id"])  # every point goes: the row moves whole
            continue
        segment[part] = next_local
        cuts.append((local, next_local))
        next_local += 1
    return segment, cuts


def _plan_rows(ctx: RepairContext, frame: Frame, art: FrameArtifact, segment: np.ndarray, cuts: list[tuple[int, int]],
               rows: dict[int, dict[str, Any]], new_id: int, plan: FramePlan) -> tuple[np.ndarray, np.ndarray]:
    """Re-render the cut segments; fill the plan's updates and inserts; the new samples."""
    if not cuts:
        return art.samples, art.sample_segment
    ids = np.array([a for a, _ in cuts] + [b for _, b in cuts], np.int32)
    res, samples, sample_segment = _rerendered(ctx, art, segment, ids)
    slot = {int(s): i for i, s in enumerate(sample_segment)}
    changed = {local: {"sample_index": slot.get(local)} for local, row in rows.items() if row["sample_index"] != slot.get(local)}
    pose = pose_of(frame)
    for k, local in enumerate(ids.tolist()):
        stats = _stats(res, k, pose, slot.get(local))
        if local in rows:
            changed[local] = stats
            continue
        old = rows[cuts[k - len(cuts)][0]]
        plan.inserts.append({"sequence_id": frame.sequence_id, "frame_id": frame.id, "frame_index": frame.index,
                             "local_id": local, "track_id": new_id, "link_score": old["link_score"], **stats})
    for local, values in changed.items():
        row = rows[local]
        plan.updates.append({"id": row["id"], **{f: row[f] for f in STAT_FIELDS}, **values})
    return samples, sample_segment


def _plan_frame(session: Session, ctx: RepairContext, frame: Frame, art: FrameArtifact, selected: np.ndarray,
                new_id: int) -> FramePlan:
    """Cut one frame and write its new artifact file; the rows to write come in the plan."""
    rows = {int(r["local_id"]): dict(r) for r in session.execute(select(*_ROW_COLUMNS).where(Segment.frame_id == frame.id)).mappings()}
    plan = FramePlan(frame.id, frame.index, frame.artifact, "", frame.n_segments, frame.n_samples, 0, 0)
    segment, cuts = _cut(art, selected, rows, plan)
    samples, sample_segment = _plan_rows(ctx, frame, art, segment, cuts, rows, new_id, plan)
    changed = {*plan.moved, *(u["id"] for u in plan.updates)}
    plan.before = [{"id": r["id"], **{f: r[f] for f in SEGMENT_FIELDS}} for r in rows.values() if r["id"] in changed]
    track = np.where(selected, new_id, art.track).astype(np.int64)
    new_art = replace(art, segment=segment, track=track, samples=samples, sample_segment=sample_segment)
    plan.artifact_after = write_revision(ctx, frame, new_art)
    plan.n_segments_after, plan.n_samples_after = max(rows) + 1 + len(cuts), len(samples)
    return plan


def plan_split(
    session: Session, ctx: RepairContext, track_id: int, guard: Guard, version: int, selector: Selector,
    frame_index: int | None, reserve: Callable[[int], TrackIds],
) -> SplitPlan:
    """Check the split, reserve the new track's id and key, cut the frames and write their new
    artifact files; nothing is locked (`session` only reads)."""
    track = read_track(session, track_id, version)
    guard.check(session, track, renew=False)  # fail early; the write step checks again under the lock
    if track.status == "merged":
        raise Conflict(f"track {track_id} was merged into another track; undo the merge first")
    picks = _pick_frames(session, ctx, track, selector, frame_index)
    moved = int(sum(int(sel.sum()) for _, _, sel in picks))
    if moved == 0:
        raise NotApplicable(f"the region selects no point of track {track_id}")
    kept_points = session.scalar(
        select(func.coalesce(func.sum(Segment.n_points), 0)).where(
            Segment.track_id == track.id, Segment.frame_index.between(track.keep_start, track.keep_end))
    )
    if moved >= int(kept_points or 0):
        raise NotApplicable(f"the region selects every point of track {track_id} in its kept frames; nothing would stay")
    plan = SplitPlan(track_id, version, reserve(track.sequence_id), frame_index, moved, selector.record, [])
    try:
        for frame, art, sel in picks:
            plan.frames.append(_plan_frame(session, ctx, frame, art, sel, plan.ids.id))
    except BaseException:
        remove_files(ctx, [f.artifact_after for f in plan.frames])
        raise
    return plan


# ----------------------------------------------------------------------------- the write step


def _write_frames(session: Session, plan: SplitPlan) -> list[int]:
    """The plan's segment and frame rows, a few statements for all frames together (the write
    transaction's length must not grow with statements per frame); the ids of the rows created."""
    table, frames = Segment.__table__, Frame.__table__
    moved = [i for fp in plan.frames for i in fp.moved]
    for k in range(0, len(moved), 10_000):
        session.execute(update(table).where(table.c.id.in_(moved[k : k + 10_000])).values(track_id=plan.ids.id))
    update_segments(session, [u for fp in plan.frames for u in fp.updates])
    inserts = [row for fp in plan.frames for row in fp.inserts]
    created = []
    if inserts:
        result = session.execute(insert(table).returning(table.c.id, sort_by_parameter_order=True), inserts)
        created = [int(i) for i in result.scalars().all()]
    update_by_id(session, frames, [{"id": fp.frame_id, "artifact": fp.artifact_after, "n_segments": fp.n_segments_after,
                                    "n_samples": fp.n_samples_after} for fp in plan.frames])
    return created


def _new_track(track: Track, plan: SplitPlan) -> Track:
    f0 = plan.frames[0].index
    return Track(id=plan.ids.id, sequence_id=track.sequence_id, key=plan.ids.key, status="pending", first_frame=f0,
                 last_frame=f0, keep_start=f0, keep_end=f0, length=0, n_samples=0, n_points=0, mean_range=0.0, version=1,
                 updated_at=utcnow())


def apply_split(session: Session, plan: SplitPlan, guard: Guard, ctx: RepairContext) -> SplitResult:
    """Lock, check and write the split in one transaction; commits. The plan's files are
    removed when it does not commit."""
    try:
        track = lock_tracks(session, {plan.track_id: plan.version}, guard)[plan.track_id]
        if track.status == "merged":
            raise Conflict(f"track {track.id} was merged into another track; undo the merge first")
        lock_frames(session, {f.frame_id: f.artifact_before for f in plan.frames})
        fields_before, links_before = track_fields(track), link_rows(session, [track.id])
        new = _new_track(track, plan)
        session.add(new)
        session.flush()
        created = _write_frames(session, plan)
        restat(session, track, ranges_from_segments=False)
        restat(session, new, ranges_from_segments=True)
        rebuild_links(session, track)
        rebuild_links(session, new)
        frames = [{"frame_id": f.frame_id, "artifact_before": f.artifact_before, "artifact_after": f.artifact_after,
                   "n_segments": f.n_segments, "n_samples": f.n_samples} for f in plan.frames]
        detail = {
            "new_track": new.id, "frame_index": plan.frame_index, "moved_points": plan.moved_points, "frames": frames,
            "segments_before": [r for f in plan.frames for r in f.before], "created_segments": created,
            "track_before": fields_before, "links_before": links_before,
            "range_before": [track.first_frame, track.last_frame], "region": plan.record,
        }
        add_event(session, track, guard.user, "split", plan.version, crud.review_state(track), detail)
        refresh_labels(session, guard.user, track, new)
        session.commit()
    except BaseException:
        session.rollback()
        remove_files(ctx, [f.artifact_after for f in plan.frames])
        raise
    return SplitResult(track, new, plan.moved_points)
