"""`predict`: run a registered model over a ready sequence and store a class per track.

The samples rendered at ingest (frame artifacts) go through the CNN a few frames at a time. A
track's predicted class is the arg-max of the mean class probabilities of its samples inside its
kept frame range; its confidence is that mean probability. Both go into `tracks.predicted_class`
and `tracks.predicted_confidence` (indexed), so the review list can sort and filter by them
(e.g. low-confidence tracks first). Tracks without a sample get NULL. Review state and versions
are not touched. When the sequence already has verified labels, the result also reports the
sample-level F of the model on them.
"""

from __future__ import annotations

from collections import defaultdict
from typing import Any

import numpy as np
from pydantic import ConfigDict, Field
from sqlalchemy import select, update
from sqlalchemy.orm import Session

from app import crud
from app.artifacts import ArtifactMissing
from app.core.errors import Conflict, Invalid, NotFound
from app.jobs.context import JobContext
from app.jobs.models_util import get_model_version
from app.jobs.registry import JobType, register
from app.models import Frame, ModelVersion, Segment, Sequence, Track
from app.schemas import JsonModel


class PredictParams(JsonModel):
    model_config = ConfigDict(extra="forbid")
    model_id: int = Field(ge=1, le=2**31 - 1)
    sequence_id: int = Field(ge=1, le=2**31 - 1)
    batch_samples: int = Field(default=512, ge=1, le=65536)
    threads: int = Field(default=0, ge=0, le=256)


def _load_model(mv: ModelVersion) -> Any:
    from pipeline.errors import DataError
    from pipeline.model import load_checkpoint

    try:
        return load_checkpoint(mv.path, "auto")
    except DataError as exc:
        raise Invalid(f"model {mv.id}: {exc}") from None


def run_predict_job(ctx: JobContext, params: PredictParams) -> dict[str, Any]:
    import torch

    from pipeline.metrics import classification_report
    from pipeline.model import predict

    with ctx.db.read() as s:
        mv = get_model_version(s, params.model_id)
        seq = s.get(Sequence, params.sequence_id)
        if seq is None:
            raise NotFound(f"sequence {params.sequence_id} not found")
        if seq.status != "ready":
            raise Conflict(f"sequence {seq.id} is {seq.status}, not ready")
        frames = s.execute(
            select(Frame.id, Frame.index, Frame.artifact).where(Frame.sequence_id == seq.id).order_by(Frame.index)
        ).all()
        seg_rows = s.execute(
            select(Segment.id, Segment.frame_id, Segment.frame_index, Segment.sample_index, Segment.track_id).where(
                Segment.sequence_id == seq.id, Segment.sample_index.is_not(None)
            )
        ).all()
        tracks = {
            int(t.id): (int(t.keep_start), int(t.keep_end))
            for t in s.execute(select(Track.id, Track.keep_start, Track.keep_end).where(Track.sequence_id == seq.id))
        }
        labels = {int(r.segment_id): int(r.class_index) for r in s.execute(crud.labels_query(seq.id)).all()}
        model_id, model_path = mv.id, mv.path
        model, meta = _load_model(mv)
    classes = meta.classes
    k = len(classes)
    want = (model.config.in_channels, model.config.size, model.config.size)

    by_frame: dict[int, list[tuple[int, int, int, int]]] = defaultdict(list)  # frame id -> (sample, seg, track, index)
    for seg_id, frame_id, frame_index, sample_index, track_id in seg_rows:
        by_frame[int(frame_id)].append((int(sample_index), int(seg_id), int(track_id or 0), int(frame_index)))

    sums: dict[int, np.ndarray] = {}
    counts: dict[int, int] = defaultdict(int)
    truth: list[int] = []
    pred_labelled: list[int] = []
    threads_before = torch.get_num_threads()
    if params.threads:
        torch.set_num_threads(params.threads)
    ctx.progress(0.0, f"model {model_id} over {len(frames)} frames")
    try:
        pending: list[tuple[np.ndarray, list[tuple[int, int, int, int]]]] = []
        n_pending = 0

        def flush() -> None:
            nonlocal n_pending
            if not pending:
                return
            probs = predict(model, np.concatenate([x for x, _ in pending]), params.batch_samples)
            rows = [r for _, rs in pending for r in rs]
            for p, (_sample, seg_id, track_id, frame_index) in zip(probs, rows, strict=True):
                if seg_id in labels:
                    truth.append(labels[seg_id])
                    pred_labelled.append(int(p.argmax()))
                keep = tracks.get(track_id)
                if keep is None or not keep[0] <= frame_index <= keep[1]:
                    continue
                acc = sums.get(track_id)
                sums[track_id] = p.astype(np.float64) if acc is None else acc + p
                counts[track_id] += 1
            pending.clear()
            n_pending = 0

        for done, (frame_id, _index, artifact) in enumerate(frames, 1):
            rows = sorted(by_frame.get(int(frame_id), []))
            if rows:
                try:
                    samples = ctx.artifacts.read_arrays(artifact, ("samples",))["samples"]
                except ArtifactMissing as exc:
                    raise Conflict(str(exc)) from None
                if samples.shape[1:] != want:
                    raise Invalid(
                        f"sequence {seq.id} has {tuple(samples.shape[1:])} samples, model {model_id} reads {want} "
                        "(channels, size, size): re-ingest the sequence with the model's sample size"
                    )
                idx = np.array([r[0] for r in rows], np.int64)
                pending.append((samples[idx], rows))
                n_pending += len(rows)
            if n_pending >= params.batch_samples:
                flush()
            if done % 20 == 0 or done == len(frames):
                flush()
                ctx.progress(0.95 * done / max(len(frames), 1), f"classified {done}/{len(frames)} frames")
        flush()
    finally:
        torch.set_num_threads(threads_before)

    updates = []
    per_class: dict[str, int] = defaultdict(int)
    for track_id in tracks:
        if track_id in sums:
            mean = sums[track_id] / counts[track_id]
            c = int(mean.argmax())
            updates.append({"id": track_id, "predicted_class": classes[c], "predicted_confidence": float(mean[c])})
            per_class[classes[c]] += 1
        else:
            updates.append({"id": track_id, "predicted_class": None, "predicted_confidence": None})
    with ctx.db.write() as s:
        for i in range(0, len(updates), 5000):
            s.execute(update(Track), updates[i : i + 5000])
        s.commit()
    result: dict[str, Any] = {
        "model_id": model_id,
        "model_path": model_path,
        "sequence_id": params.sequence_id,
        "frames": len(frames),
        "samples": len(seg_rows),
        "tracks_predicted": sum(per_class.values()),
        "tracks_without_samples": len(tracks) - sum(per_class.values()),
        "predicted_per_class": dict(sorted(per_class.items())),
    }
    if truth:
        rep = classification_report(np.array(truth), np.array(pred_labelled), k, tuple(classes))
        result["verified_labels"] = {"samples": len(truth), "mean_f": rep.to_dict().get("mean_f"),
                                     "f": {c: (None if np.isnan(v) else round(float(v), 2))
                                           for c, v in zip(classes, rep.f, strict=True)}}
    ctx.progress(1.0, f"{result['tracks_predicted']} tracks predicted")
    return result


def prepare_predict(s: Session, params: PredictParams) -> None:
    get_model_version(s, params.model_id)
    seq = s.get(Sequence, params.sequence_id)
    if seq is None:
        raise NotFound(f"sequence {params.sequence_id} not found")
    if seq.status != "ready":
        raise Conflict(f"sequence {seq.id} is {seq.status}, not ready: ingest it first")


register(
    JobType(
        name="predict",
        params=PredictParams,
        handler=run_predict_job,
        admin_only=True,
        description="Classify every track of a sequence with a registered model (predicted class + confidence).",
        prepare=prepare_predict,
    )
)
