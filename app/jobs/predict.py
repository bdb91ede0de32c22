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
from sqlalchemy.orm import Session

from app import crud
from app.core.errors import Invalid
from app.crud.frames import frame_artifacts, sample_segments
from app.crud.model_versions import ChosenModel, choose_model, ready_sequence, score_stored_samples
from app.crud.statistics import segment_classes
from app.crud.tracks import set_predictions, track_ranges
from app.jobs.context import JobContext
from app.jobs.registry import JobType, register
from app.schemas import JsonModel


class PredictParams(JsonModel):
    model_config = ConfigDict(extra="forbid")
    model_id: int | None = Field(default=None, ge=1, le=2**31 - 1,
                                 description="None = the newest model, or the shipped default model while none is registered.")
    sequence_id: int = Field(ge=1, le=2**31 - 1)
    batch_samples: int = Field(default=512, ge=1, le=65536)
    threads: int = Field(default=0, ge=0, le=256)


def _load_model(chosen: ChosenModel) -> Any:
    from pipeline.errors import DataError
    from pipeline.model import load_checkpoint

    try:
        return load_checkpoint(chosen.path, "auto")
    except DataError as exc:
        raise Invalid(f"{chosen.name}: {exc}") from None


def _track_sums(
    probs: np.ndarray, seg_rows: list[Any], tracks: dict[int, tuple[int, int]], labels: dict[int, int]
) -> tuple[dict[int, np.ndarray], dict[int, int], list[int], list[int]]:
    """Per track the sum (K,) and count of its kept samples' probabilities (N, K); and the
    verified labels with the arg-max of their samples."""
    sums: dict[int, np.ndarray] = {}
    counts: dict[int, int] = defaultdict(int)
    truth: list[int] = []
    pred_labelled: list[int] = []
    for p, row in zip(probs, seg_rows, strict=True):
        seg_id, track_id, frame_index = int(row.id), int(row.track_id or 0), int(row.frame_index)
        if seg_id in labels:
            truth.append(labels[seg_id])
            pred_labelled.append(int(p.argmax()))
        keep = tracks.get(track_id)
        if keep is None or not keep[0] <= frame_index <= keep[1]:
            continue
        acc = sums.get(track_id)
        sums[track_id] = p.astype(np.float64) if acc is None else acc + p
        counts[track_id] += 1
    return sums, counts, truth, pred_labelled


def run_predict_job(ctx: JobContext, params: PredictParams) -> dict[str, Any]:
    import torch

    from pipeline.metrics import classification_report

    with ctx.db.read() as s:
        chosen = choose_model(s, params.model_id)
        seq = ready_sequence(s, params.sequence_id)
        artifact_of = frame_artifacts(s, seq.id)
        seg_rows = sample_segments(s, seq.id)  # in frame order
        tracks, points = {}, {}
        for t in track_ranges(s, seq.id):
            tracks[int(t.id)], points[int(t.id)] = (int(t.keep_start), int(t.keep_end)), int(t.n_points)
        labels = segment_classes(s, seq.id)
        model_id, model_path = chosen.id, chosen.path
        model, meta = _load_model(chosen)
    classes = meta.classes
    k = len(classes)
    # (artifact, sample index) of every sample, in frame order
    refs = [(artifact_of[int(r.frame_id)], int(r.sample_index)) for r in seg_rows]

    def scored(done: int, total: int) -> None:
        if done % 20 == 0 or done == total:
            ctx.progress(0.95 * done / total, f"classified {done}/{total} frames")

    threads_before = torch.get_num_threads()
    if params.threads:
        torch.set_num_threads(params.threads)
    ctx.progress(0.0, f"{chosen.name} over {len(artifact_of)} frames")
    try:
        probs = score_stored_samples(ctx.artifacts, refs, model, chosen.name, params.batch_samples,
                                     on_file=scored).probs
    finally:
        torch.set_num_threads(threads_before)
    sums, counts, truth, pred_labelled = _track_sums(probs, seg_rows, tracks, labels)

    updates = []
    per_class: dict[str, int] = defaultdict(int)
    for track_id in tracks:
        if track_id in sums:
            mean = sums[track_id] / counts[track_id]
            c = int(mean.argmax())
            updates.append({"id": track_id, "predicted_class": classes[c], "predicted_confidence": float(mean[c]),
                            "priority": crud.queue_priority(points[track_id], float(mean[c]))})
            per_class[classes[c]] += 1
        else:
            updates.append({"id": track_id, "predicted_class": None, "predicted_confidence": None,
                            "priority": crud.queue_priority(points[track_id], None)})
    with ctx.db.write() as s:
        set_predictions(s, updates)
    result: dict[str, Any] = {
        "model_id": model_id,
        "model_path": model_path,
        "sequence_id": params.sequence_id,
        "frames": len(artifact_of),
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
    from app.crud.label_sets import label_set_of
    from app.services.label_sets import require_model_label_set

    chosen = choose_model(s, params.model_id)
    seq = ready_sequence(s, params.sequence_id)
    require_model_label_set(chosen.name, chosen.path, label_set_of(seq))


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
