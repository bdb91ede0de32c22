"""`train`: train the sample CNN on the verified labels (+ constraints) of ready sequences.

1. Read the labelled samples and must-link pairs (`model_versions.load_training_set`): verified pairs
   of accepted tracks (the paper), automatic ones weighted by their association score, or none.
2. Split the labelled samples 70/30 into train/validation by track (`split_by_group`), so
   near-identical samples of one track never sit on both sides, and leave the pairs that touch a
   validation track out of training (as the paper experiment does); or validate on other sequences.
3. Train (`pipeline.training.train`) with the library's defaults (`TrainingConfig`, the config
   of the paper experiment's constraint100) and the job's options; every few steps the progress and, after each epoch, the
   epoch's loss and validation F go into the job row (`message`, and `result.history` while it
   runs). A cancel stops the run at the next step; nothing is registered then.
4. Write the checkpoint under `<data_dir>/models/train_<job>/` and register a model version with
   its metrics (validation report of the selected epoch, history, data counts).
A retried job whose model is already registered returns it.
"""

from __future__ import annotations

import json
import shutil
from collections.abc import Callable
from dataclasses import dataclass
from typing import Annotated, Any, Literal

import numpy as np
from pydantic import ConfigDict, Field
from sqlalchemy.orm import Session

from app.core.errors import Conflict, Invalid
from app.crud.datasets import get_sequence
from app.crud.jobs import job_owner, update_running_job
from app.crud.label_sets import common_label_set
from app.crud.model_versions import (
    TrainingSet,
    load_training_set,
    model_dir,
    model_version_for_job,
    ready_sequence,
    register_model_version,
    sample_config_for,
)
from app.jobs.context import JobContext, JobStopped
from app.jobs.registry import JobType, register
from app.jobs.training_params import job_training_config, with_training_fields
from app.schemas import JsonModel
from pipeline.config import SampleConfig, TrainingConfig
from pipeline.label_sets import LabelSet

MODEL_SIZES: dict[str, dict[str, int]] = {
    "tiny": {"width": 8, "max_width": 16, "depth": 2},
    "small": {"width": 16, "max_width": 64, "depth": 3},
    "default": {},
    "large": {"width": 48, "max_width": 192, "depth": 4},
}

Id = Field(ge=1, le=2**31 - 1)
SequenceId = Annotated[int, Field(ge=1, le=2**31 - 1)]  # in the schema, so that clients see the range


class _TrainJobParams(JsonModel):
    model_config = ConfigDict(extra="forbid")
    sequence_ids: list[SequenceId] = Field(min_length=1, max_length=1000)  # labels and constraints from these
    val_sequence_ids: list[SequenceId] = Field(default_factory=list, max_length=1000)  # else a split by track
    val_fraction: float = Field(default=0.3, ge=0.0, lt=1.0)
    constraints: Literal["verified", "automatic", "none"] = "verified"
    min_score: float = Field(default=0.0, ge=0.0, le=1.0)  # automatic pairs below this are left out
    model_size: Literal["tiny", "small", "default", "large"] = "default"
    size: int | None = Field(default=None, ge=8, le=1024)  # expected sample size; None = as ingested
    name: str | None = Field(default=None, max_length=128)


# The training options (epochs, lr, ...) are TrainingConfig's, with its defaults.
TrainParams = with_training_fields("TrainParams", _TrainJobParams, TrainingConfig())


def train_config(params: Any) -> TrainingConfig:
    """The TrainingConfig a train job runs: the library's defaults, the job's options, and the
    constraint source's rule (`TrainingConfig.for_constraints`)."""
    return job_training_config(params, TrainingConfig()).for_constraints(params.constraints)


def _record(ctx: JobContext, result: dict[str, Any]) -> None:
    """Write the running result (per-epoch history) into the job row."""
    with ctx.db.write() as s:
        update_running_job(s, ctx.job_id, ctx.worker_id, {"result": result})


@dataclass
class _JobData:
    """What a train job reads: the training set, the sample config its samples were made with,
    the optional validation sequences' set and the user who queued the job."""

    ts: TrainingSet
    label_set: LabelSet  # the sequences' one set: the model's outputs are its sample classes
    samples_cfg: SampleConfig
    val_set: TrainingSet | None
    user_id: int | None


def _read(ctx: JobContext, params: Any) -> _JobData:
    ctx.progress(0.0, "reading labels and constraints")

    def reading(done: int, total: int) -> None:
        if done == total or done % 50 == 0:
            ctx.progress(0.05 * done / total, f"reading samples: {done}/{total} frame files")

    with ctx.db.read() as s:
        ts = load_training_set(
            s, ctx.artifacts, params.sequence_ids, params.constraints, params.min_score, progress=reading
        )
        label_set = common_label_set(s, [*params.sequence_ids, *params.val_sequence_ids])
        seq = get_sequence(s, params.sequence_ids[0])  # load_training_set checked it
        samples_cfg = sample_config_for(ctx.settings, seq)
        val_set = load_training_set(s, ctx.artifacts, params.val_sequence_ids, "none") if params.val_sequence_ids else None
        user_id = job_owner(s, ctx.job_id)
    shape = ts.data.samples.shape[1:]
    if params.size is not None and shape[1] != params.size:
        raise Invalid(f"the sequences' samples are {shape[1]}x{shape[2]}, params.size asks for {params.size}")
    if shape != (samples_cfg.channels, samples_cfg.size, samples_cfg.size):
        # the stored samples are the truth; adopt their size/channels
        samples_cfg = samples_cfg.model_copy(update={"size": int(shape[1]), "foreground_channel": shape[0] == 4})
    if len(ts.data.labelled) == 0:
        raise Invalid(f"sequences {params.sequence_ids} hold no verified labels: review some tracks first")
    return _JobData(ts, label_set, samples_cfg, val_set, user_id)


def _split(job: _JobData, params: Any) -> tuple[Any, Any, np.ndarray, np.ndarray]:
    """(training data, validation samples or None, indices of the training labels, (P,) bool the
    pairs trained on): the validation sequences, else a split by track of the labels, else no
    validation."""
    from pipeline.training import LabelledSamples, TrainingData, split_by_group

    data = job.ts.data
    labels, shape = data.labels, data.samples.shape[1:]
    pair_sel = np.ones(len(data.pairs), bool)
    if job.val_set is not None:
        train_sel = np.arange(len(labels))
        val = LabelledSamples(job.val_set.data.samples[job.val_set.data.labelled], job.val_set.data.labels)
        if val.samples.shape[1:] != shape:
            raise Invalid(f"validation samples are {val.samples.shape[1:]}, training samples {shape}")
    elif params.val_fraction > 0:
        train_sel, val_sel = split_by_group(labels, job.ts.label_track_ids, params.val_fraction, params.seed)
        val = LabelledSamples(data.samples[data.labelled[val_sel]], labels[val_sel])
        # validation tracks stay out of training altogether, as in the paper experiment: a pair
        # touching one would carry a training label onto it (label closure over a stitch)
        val_tracks = np.unique(job.ts.label_track_ids[val_sel])
        pair_sel = ~np.isin(job.ts.track_ids[data.pairs], val_tracks).any(axis=1)
    else:
        train_sel, val = np.arange(len(labels)), None
    train_data = TrainingData.build(
        data.samples, data.labelled[train_sel], labels[train_sel], data.pairs[pair_sel], data.pair_weights[pair_sel]
    )
    return train_data, val, train_sel, pair_sel


def _counts(job: _JobData, train_sel: np.ndarray, pair_sel: np.ndarray, val: Any) -> dict[str, Any]:
    classes = job.label_set.sample_class_names
    data = job.ts.data
    binc = np.bincount(data.labels[train_sel], minlength=len(classes))
    return {
        "labelled_train": int(len(train_sel)),
        "labelled_val": 0 if val is None else len(val),
        "pairs": int(pair_sel.sum()),
        "pairs_verified": int(job.ts.pair_verified[pair_sel].sum()),
        "labels_per_class": {name: int(binc[i]) for i, name in enumerate(classes)},
    }


def _reporter(ctx: JobContext, counts: dict[str, Any]) -> Callable[[Any], None]:
    """The training report callback: progress into the job row, and each finished epoch's loss
    and validation F into its running result."""
    history: list[dict[str, Any]] = []

    def on_progress(p: Any) -> None:
        msg = f"epoch {p.epoch + 1}/{p.epochs} step {p.step}/{p.steps_per_epoch} loss {p.loss:.4f}"
        if p.epoch_done:
            val_f = None if p.val_f is None or not np.isfinite(p.val_f) else round(float(p.val_f), 3)
            rec = {"epoch": p.epoch, "loss": round(float(p.loss), 6), "val_f": val_f}
            history.append(rec)
            msg += "" if rec["val_f"] is None else f" val F {rec['val_f']:.1f}"
            _record(ctx, {"running": True, "history": history, "data": counts})
        try:
            ctx.progress(0.05 + 0.9 * p.fraction, msg)
        except JobStopped:
            pass  # the flag is set: `stop` ends training at the next step

    return on_progress


def run_train(ctx: JobContext, params: Any) -> dict[str, Any]:
    from pipeline.config import ModelConfig
    from pipeline.training import train

    with ctx.db.read() as s:
        done = model_version_for_job(s, ctx.job_id)
        if done is not None:
            return {"model_id": done.id, "path": done.path, "metrics": _summary(done.metrics or {})}
    job = _read(ctx, params)
    train_data, val, train_sel, pair_sel = _split(job, params)
    classes = job.label_set.sample_class_names
    model_cfg = ModelConfig(**MODEL_SIZES[params.model_size], num_classes=len(classes))
    cfg = train_config(params)
    counts = _counts(job, train_sel, pair_sel, val)
    out = model_dir(ctx.settings, "train", ctx.job_id)
    ctx.progress(0.05, f"training on {counts['labelled_train']} labels and {counts['pairs']} pairs")
    result = train(
        train_data, cfg, model_cfg, job.samples_cfg, val=val, checkpoint_dir=out, report=_reporter(ctx, counts),
        stop=lambda: ctx.cancelled.is_set() or ctx.lease_lost.is_set(), classes=classes, label_set=job.label_set.name,
    )
    if result.cancelled:
        shutil.rmtree(out, ignore_errors=True)
        ctx.checkpoint()  # raises JobStopped
    if result.checkpoint is None:
        raise Conflict("training finished no epoch")
    metrics = json.loads(json.dumps(result.metrics, default=float)) | {"data": counts}
    config = {
        "params": params.model_dump(mode="json"),
        "training": cfg.model_dump(mode="json"),
        "model": model_cfg.model_dump(mode="json"),
        "samples": job.samples_cfg.model_dump(mode="json"),
    }
    name = params.name or f"train {params.constraints} seq {','.join(map(str, params.sequence_ids))} (job {ctx.job_id})"
    with ctx.db.write() as s:
        mv = register_model_version(
            s, name=name, kind="train", path=result.checkpoint.resolve(), metrics=metrics, config=config,
            job_id=ctx.job_id, created_by_id=job.user_id,
        )
        s.commit()
        model_id = mv.id
    ctx.progress(1.0, f"model {model_id} registered")
    return {"model_id": model_id, "path": str(result.checkpoint.resolve()), "metrics": _summary(metrics)}


def _summary(metrics: dict[str, Any]) -> dict[str, Any]:
    val = metrics.get("val") or {}
    return {
        "val_mean_f": val.get("mean_f"),
        "selected_epoch": metrics.get("selected_epoch"),
        "epochs_run": metrics.get("epochs_run"),
        "data": metrics.get("data"),
    }


def prepare_train(s: Session, params: Any) -> None:
    for sid in (*params.sequence_ids, *params.val_sequence_ids):
        ready_sequence(s, sid)
    common_label_set(s, [*params.sequence_ids, *params.val_sequence_ids])


register(
    JobType(
        name="train",
        params=TrainParams,
        handler=run_train,
        admin_only=True,
        description="Train the sample CNN on verified labels and (verified or automatic) constraints; "
        "registers the model with its metrics.",
        prepare=prepare_train,
    )
)
