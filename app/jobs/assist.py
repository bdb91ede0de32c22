"""`assist`: the model in the review loop. It classifies every track of a sequence from the
operator's reviews so far, and orders the review queue by what a review would correct.

1. Read the sequence's samples, their segments' size, range and height, and the classes of the
   samples of tracks an operator reviewed (bulk-accepted classes are the model's own guesses and
   are not trained on); the samples of discarded tracks are `no_object`; a sample whose segment
   lies (`REGION_SHARE` of its points) in an operator's regions of one object class has that
   class: a prism drawn over a hedge labels the tracks in it as surely as reviews would.
2. Score every sample with the base CNN: the newest model trained on this sequence, else the
   shipped default model (its embedding and class probabilities), of any label set: the head
   reads its view, and learns the sequence's own classes from the reviews.
3. Refit the head (`pipeline.assist`) on those samples and classify every sample.
4. Per track, the mean probability of its kept samples gives its predicted class and confidence,
   and its queue priority (`crud.queue_priority`) from the points of its kept frames that no
   operator's region labels (a review cannot change those); the reviewed tracks' held-out
   predictions give the precision a bulk accept's preview shows (`result.held_out`; the samples
   regions label are learnt in every fold, never held out: a bulk takes tracks no operator has
   looked at, and the check measures it on tracks an operator reviewed).

The worker queues it by itself (`schedule`): once when a sequence becomes ready, then each time
`assist_every` more review events have come in or a region was drawn or undone. One runs at a
time per sequence; reviews that arrive meanwhile start the next run when it ends, so a run is
never restarted for every action.
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np
from pydantic import ConfigDict, Field
from sqlalchemy.orm import Session

from app import crud
from app.artifacts import ArtifactStore
from app.core.config import Settings
from app.core.db import Database
from app.crud.frames import frame_artifacts, sample_segments
from app.crud.ground_regions import region_operations
from app.crud.model_versions import (
    ChosenModel,
    choose_model,
    newest_model_trained_on,
    ready_sequence,
    score_stored_samples,
    stored_arrays,
)
from app.crud.review import review_events_after
from app.crud.statistics import segment_classes
from app.crud.tracks import set_predictions, track_ranges
from app.jobs.context import JobContext
from app.jobs.policy import ADMIN_PRIORITY
from app.jobs.registry import JobType, register
from app.schemas import JsonModel
from app.services.point_labels import RegionCover, frame_poses, region_cover, stored_regions
from app.services.repair import GEOMETRY_ACTIONS

# the review actions that bring the model something new (bulk accepts are its own predictions)
REVIEW_ACTIONS = (*crud.REVIEW_ACTIONS, *GEOMETRY_ACTIONS)  # what an operator did by hand
REGION_SHARE = 0.9  # of a segment's points in regions of one object class: the head learns it as that class


class AssistParams(JsonModel):
    model_config = ConfigDict(extra="forbid")
    sequence_id: int = Field(ge=1, le=2**31 - 1)
    model_id: int | None = Field(default=None, ge=1, le=2**31 - 1, description=(
        "The base CNN; None = the newest model trained on this sequence, else the shipped default."))
    after_event: int = Field(default=0, ge=0, le=2**62, description="The newest review event the run includes.")
    regions: int = Field(default=0, ge=0, le=2**62,
                         description="The region operations (drawn, undone) the run includes.")
    seed: int = Field(default=0, ge=0, le=2**31 - 1)


def base_model(session: Session, sequence_id: int, model_id: int | None) -> ChosenModel:
    """The CNN whose view of the samples the head reads (see AssistParams.model_id)."""
    if model_id is not None:
        return choose_model(session, model_id)
    mv = newest_model_trained_on(session, sequence_id)
    if mv is not None:
        return ChosenModel(mv.id, mv.path)
    from pipeline.model import default_model_path

    return ChosenModel(None, str(default_model_path()))


def _read(session: Session, sequence_id: int) -> dict[str, Any]:
    """The sequence's samples (frame order), tracks, reviewed labels, label set and regions."""
    seq = ready_sequence(session, sequence_id)
    artifact = frame_artifacts(session, seq.id)
    segs = sample_segments(session, seq.id)
    tracks = track_ranges(session, seq.id)
    reviewed = segment_classes(session, seq.id, source="review")
    label_set = crud.label_set_of(seq)
    regions = stored_regions(session, seq.id, label_set)
    return {"artifact": artifact, "segs": segs, "tracks": tracks, "reviewed": reviewed, "label_set": label_set,
            "regions": regions, "frames": frame_poses(session, seq.id) if regions else []}


def _training_labels(data: dict[str, Any], group: np.ndarray, k: int) -> np.ndarray:
    """Per sample the class the head learns it as, -1 for none: the reviewed ones their class,
    those of discarded tracks (in their kept range) k, NO_OBJECT."""
    reviewed = data["reviewed"]
    discarded = np.array([t.status == "discarded" for t in data["tracks"]] + [False])
    cls = np.full(len(data["segs"]), -1, np.int64)
    for j, r in enumerate(data["segs"]):
        if int(r.id) in reviewed:
            cls[j] = reviewed[int(r.id)]
        elif discarded[group[j]]:
            cls[j] = k
    return cls


def _region_labels(cover: RegionCover, group: np.ndarray, k: int) -> np.ndarray:
    """Per sample the object class (0..k-1) regions give `REGION_SHARE` of its segment's points
    when it is in a kept range, else -1."""
    counts = cover.sample_classes[:, :k]
    share = counts.max(1) >= REGION_SHARE * np.maximum(cover.sample_points, 1)
    return np.where(share & (cover.sample_points > 0) & (group >= 0), counts.argmax(1), -1)


def _features(ctx: JobContext, data: dict[str, Any], chosen: ChosenModel, batch: int) -> Any:
    from pipeline.assist import SampleFeatures, segment_stats
    from pipeline.model import load_checkpoint

    model, meta = load_checkpoint(chosen.path, "auto")
    segs = data["segs"]
    refs = [(data["artifact"][int(r.frame_id)], int(r.sample_index)) for r in segs]
    scores = score_stored_samples(ctx.artifacts, refs, model, chosen.name, batch, features=True)
    stats = segment_stats(np.array([r.n_points for r in segs]), np.array([r.range for r in segs]),
                          np.array([r.cz for r in segs]), _shapes(ctx.artifacts, refs))
    return SampleFeatures(scores.features, scores.probs, stats), meta.classes


def _shapes(artifacts: ArtifactStore, refs: list[tuple[str, int]]) -> np.ndarray:
    """(len(refs), len(SHAPE_FEATURES)) the shape of each sample's segment, from its frame file."""
    from pipeline.assist import SHAPE_FEATURES, segment_shapes

    out = np.zeros((len(refs), len(SHAPE_FEATURES)), np.float32)
    for dst, src, a in stored_arrays(artifacts, refs, ("points", "intensity", "segment", "sample_segment")):
        out[dst] = segment_shapes(a["points"], a["intensity"], a["segment"], a["sample_segment"][src])
    return out


def _kept_group(data: dict[str, Any]) -> tuple[np.ndarray, list[Any]]:
    """Per sample the position of its track in `tracks` when the sample is in the kept range, else -1."""
    tracks = data["tracks"]
    pos = {int(t.id): i for i, t in enumerate(tracks)}
    group = np.full(len(data["segs"]), -1, np.int64)
    for j, r in enumerate(data["segs"]):
        i = pos.get(int(r.track_id or 0))
        if i is not None and tracks[i].keep_start <= r.frame_index <= tracks[i].keep_end:
            group[j] = i
    return group, tracks


def _held_out_record(held: Any, classes: tuple[str, ...], points: list[int | None]) -> dict[str, list[Any]] | None:
    """The reviewed tracks' held-out predictions as JSON, with each track's points
    (crud.bulk_preview reads the precision and the size floor at any threshold from it); None
    with too few reviews to hold any out."""
    if held is None:
        return None
    return {"truth": [classes[i] for i in held.truth], "predicted": [classes[i] for i in held.predicted],
            "confidence": [round(float(c), 4) for c in held.confidence], "points": points}


def _points(tracks: list[Any], positions: np.ndarray) -> list[int | None]:
    """The points of the tracks at `positions` in `tracks` (None for -1: samples of no kept track)."""
    return [int(tracks[j].n_points) if j >= 0 else None for j in positions]


def _write(ctx: JobContext, tracks: list[Any], mean: np.ndarray, counts: np.ndarray, classes: tuple[str, ...],
           in_regions: dict[int, int]) -> int:
    """Each track's predicted class (`classes`, NO_OBJECT last), its confidence and priority
    (`in_regions`: per track id, its points that regions label)."""
    rows = []
    for i, t in enumerate(tracks):
        has = counts[i] > 0
        conf = float(mean[i].max()) if has else None
        free = max(int(t.n_points) - in_regions.get(int(t.id), 0), 0)
        rows.append({"id": int(t.id), "predicted_class": classes[int(mean[i].argmax())] if has else None,
                     "predicted_confidence": conf, "priority": crud.queue_priority(free, conf)})
    with ctx.db.write() as s:
        set_predictions(s, rows)
    return int((counts > 0).sum())


def run_assist(ctx: JobContext, params: AssistParams) -> dict[str, Any]:
    from pipeline.assist import NO_OBJECT, assist_probs, held_out_tracks, track_means

    t0 = time.perf_counter()
    with ctx.db.read() as s:
        data = _read(s, params.sequence_id)
        chosen = base_model(s, params.sequence_id, params.model_id)
    label_set = data["label_set"]
    ctx.progress(0.05, f"scoring {len(data['segs'])} samples with {chosen.name}")
    features, cnn_classes = _features(ctx, data, chosen, 512)
    k = len(label_set.sample_class_names)
    speaks = tuple(cnn_classes) == label_set.sample_class_names
    classes = (*label_set.sample_class_names, NO_OBJECT)
    ctx.progress(0.6, "fitting the head on the reviews and regions")
    group, tracks = _kept_group(data)
    cover = region_cover(data["frames"], data["regions"], ctx.artifacts, tracks, data["segs"],
                         len(label_set.point_classes))
    reviewed = _training_labels(data, group, k)
    taught = np.where(reviewed >= 0, reviewed, _region_labels(cover, group, k))
    labelled, labels = np.flatnonzero(reviewed >= 0), reviewed[reviewed >= 0]
    probs = assist_probs(features, np.flatnonzero(taught >= 0), taught[taught >= 0], k, speaks, params.seed)
    from_regions = np.flatnonzero((taught >= 0) & (reviewed < 0))
    held = held_out_tracks(features, labelled, labels, group[labelled], k, speaks, params.seed,
                           always=(from_regions, taught[from_regions]))
    predicted = 0
    if probs is not None:
        mean, counts = track_means(probs, group, len(tracks))
        predicted = _write(ctx, tracks, mean, counts, classes, cover.track_points)
    ctx.progress(1.0, f"{predicted} tracks predicted from {len(np.unique(group[labelled]))} reviewed tracks")
    return {"sequence_id": params.sequence_id, "model_id": chosen.id, "model_path": chosen.path,
            "after_event": params.after_event, "regions": params.regions, "samples": len(data["segs"]),
            "reviewed_samples": int(len(labelled)), "region_samples": len(from_regions),
            "reviewed_classes": sorted({classes[i] for i in labels}), "tracks_predicted": predicted,
            "held_out": _held_out_record(held, tuple(classes), _points(tracks, np.unique(group[labelled]))),
            "seconds": round(time.perf_counter() - t0, 2)}


def _review_events(session: Session, sequence_id: int, after: int) -> tuple[int, int]:
    """(count, newest id) of the sequence's review events after event id `after`."""
    n, newest = review_events_after(session, sequence_id, REVIEW_ACTIONS, after)
    return n, max(newest, after)


def _runs(session: Session) -> dict[int, tuple[bool, int, int]]:
    """Per sequence: whether an assist run is queued or running, the newest review event and the
    region operations a run has taken in (a failed run's too, so a failing run waits for more
    reviews before the next)."""
    out: dict[int, tuple[bool, int, int]] = {}
    for status, p in crud.job_runs(session, "assist"):
        seq = int(p.get("sequence_id", 0))
        active, last, regions = out.get(seq, (False, -1, 0))
        out[seq] = (active or status in ("queued", "running"), max(last, int(p.get("after_event", 0))),
                    max(regions, int(p.get("regions", 0))))
    return out


def _due(session: Session, sequence_id: int, run: tuple[bool, int, int] | None, every: int) -> tuple[int, int] | None:
    """(newest review event id, region operations) when the sequence needs an assist run now,
    else None."""
    if run is not None and run[0]:
        return None  # one at a time: reviews arriving meanwhile are taken by the next run
    n, newest = _review_events(session, sequence_id, 0 if run is None else run[1])
    regions = region_operations(session, sequence_id)
    return (newest, regions) if run is None or n >= every or regions != run[2] else None


def schedule(db: Database, settings: Settings) -> list[int]:
    """Queue an assist run for every ready sequence that is due (module docstring); returns the
    new jobs' ids. Off when `settings.assist_every` is 0."""
    if settings.assist_every <= 0:
        return []
    with db.read() as s:
        runs = _runs(s)
        ready = crud.ready_sequence_ids(s)
        due = {q: a for q in ready
               if (a := _due(s, q, runs.get(q), settings.assist_every)) is not None}
    if not due:
        return []
    with db.write() as s:
        if any(_runs(s).get(q, (False, 0, 0))[0] for q in due):
            return []  # another worker queued one meanwhile; the next poll looks again
        jobs = [crud.create_job(s, "assist", AssistParams(sequence_id=q, after_event=a, regions=r).model_dump(), None,
                                priority=ADMIN_PRIORITY) for q, (a, r) in due.items()]
        s.commit()
        return [j.id for j in jobs]


def prepare_assist(session: Session, params: AssistParams) -> None:
    ready_sequence(session, params.sequence_id)
    base_model(session, params.sequence_id, params.model_id)


register(
    JobType(
        name="assist",
        params=AssistParams,
        handler=run_assist,
        admin_only=True,
        description="The model in the review loop: classify every track from the reviews so far and order the "
        "review queue (queued by the worker itself as reviews come in).",
        prepare=prepare_assist,
        max_run_seconds=1800.0,
    )
)
