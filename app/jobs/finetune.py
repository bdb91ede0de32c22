"""`finetune`: a pretrained model trained further on a new sequence's confirmed anchors and
constraints; registers the result as a new model version (parent = the pretrained one) and can
queue a `predict` job with it.

Training data (read with app.crud.model_versions):
- labels: the sequence's labels table, which holds every labelled track's samples (a confirmed
  track-level anchor labels its whole track) plus the confirmed sample-level anchors;
- constraints: `verified` (pairs of accepted tracks, weight 1, the paper), `automatic` (pairs of
  every non-discarded track, weighted by the association score) or `none`.
"""

from __future__ import annotations

from typing import Any, Literal

import numpy as np
from pydantic import ConfigDict, Field, ValidationError

from app.core.errors import Conflict, Invalid, ServiceError
from app.crud import model_versions
from app.crud.anchors import confirmed_sample_anchors
from app.jobs.context import JobContext
from app.jobs.policy import OperatorRule
from app.jobs.registry import JobType, get_job_type, register
from app.jobs.training_params import job_training_config, with_training_fields
from app.schemas import JsonModel
from pipeline.config import TrainingConfig


class _FinetuneJobParams(JsonModel):
    model_config = ConfigDict(extra="forbid")
    sequence_id: int = Field(ge=1, le=2**31 - 1, description="The new scene.")
    model_id: int = Field(ge=1, le=2**31 - 1, description="The pretrained model (a model version id).")
    constraints: Literal["verified", "automatic", "none"] = "verified"
    min_score: float = Field(default=0.0, ge=0.0, le=1.0, description="automatic: drop pairs scored below this.")
    balance: bool = Field(default=True, description="Draw the anchors' classes evenly (see pipeline/finetune.py).")
    name: str | None = Field(default=None, max_length=128)
    predict: bool = Field(default=False, description="Queue a predict job on the sequence with the new model.")


# The training options (epochs, lr, ...) are TrainingConfig's, with its fine-tuning defaults.
FinetuneParams = with_training_fields("FinetuneParams", _FinetuneJobParams, TrainingConfig().finetuning())


def finetune_job_config(params: Any) -> TrainingConfig:
    """The TrainingConfig a finetune job runs: the library's fine-tuning defaults with the job's
    options; pairs always weighted (verified ones weigh 1)."""
    cfg = job_training_config(params, TrainingConfig().finetuning())
    return cfg.model_copy(update={"weighted_pairs": True})


def prepare_finetune(s: Any, params: Any) -> None:
    from app.crud.label_sets import label_set_of
    from app.services.label_sets import require_model_label_set

    seq = model_versions.ready_sequence(s, params.sequence_id)
    mv = model_versions.get_model_version(s, params.model_id)
    require_model_label_set(f"model {mv.id}", mv.path, label_set_of(seq))


def _training_data(ctx: JobContext, params: Any, classes: tuple[str, ...]) -> Any:
    """TrainingData of the sequence: labels + sample anchors + constraints (see module doc)."""
    from pipeline.training import TrainingData

    with ctx.db.read() as s:
        anchors = confirmed_sample_anchors(s, params.sequence_id)
        try:
            ts = model_versions.load_training_set(
                s, ctx.artifacts, [params.sequence_id], params.constraints, params.min_score, classes
            )
            base, seg_ids = ts.data, ts.segment_ids
        except Invalid:
            if not anchors:
                raise Invalid(
                    f"sequence {params.sequence_id} has no confirmed anchors, labels or constraints to fine-tune on"
                ) from None
            base, seg_ids = None, np.zeros(0, np.int64)
        have = {int(v): i for i, v in enumerate(seg_ids)}
        labelled_segments = {int(seg_ids[i]) for i in (base.labelled if base is not None else [])}
        extra = [seg for seg, _ in anchors if seg not in have]
        extra_samples = None
        if extra:
            extra_samples, _ = model_versions.read_samples(s, ctx.artifacts, np.array(extra, np.int64))
    for _seg, cls in anchors:
        if cls not in classes:
            raise Invalid(f"anchor class {cls!r} is not a class of the model ({', '.join(classes)})")
    if base is None:
        samples = extra_samples
        labelled, labels = np.zeros(0, np.int64), np.zeros(0, np.int64)
        pairs, weights = np.zeros((0, 2), np.int64), np.zeros(0, np.float32)
    else:
        samples = base.samples if extra_samples is None else np.concatenate([base.samples, extra_samples])
        labelled, labels, pairs, weights = base.labelled, base.labels, base.pairs, base.pair_weights
    for j, seg in enumerate(extra):
        have[seg] = (0 if base is None else len(base.samples)) + j
    # sample anchors on segments already labelled through their track keep the track's label
    add = [(have[seg], classes.index(cls)) for seg, cls in anchors if seg not in labelled_segments]
    if add:
        labelled = np.concatenate([labelled, np.array([a for a, _ in add], np.int64)])
        labels = np.concatenate([labels, np.array([c for _, c in add], np.int64)])
    if len(labelled) == 0:
        raise Invalid(f"sequence {params.sequence_id} has no confirmed anchors or labels: confirm some proposals first")
    if params.balance:
        from pipeline.finetune import balance_classes

        labelled, labels = balance_classes(labelled, labels)
    return TrainingData.build(samples, labelled, labels, pairs, weights)


def run_finetune(ctx: JobContext, params: Any) -> dict[str, Any]:
    from pipeline.finetune import finetune
    from pipeline.model import load_checkpoint

    with ctx.db.read() as s:
        prepare_finetune(s, params)
        done = model_versions.model_version_for_job(s, ctx.job_id)
        if done is not None:  # a retry after the model was registered
            return {"model_id": done.id, "path": done.path, "metrics": done.metrics, "predict_job_id": None}
        parent = model_versions.get_model_version(s, params.model_id)
        parent_id, parent_path, parent_name = parent.id, parent.path, parent.name
    model, meta = load_checkpoint(parent_path)
    classes = tuple(meta.classes[: meta.model_config.num_classes])
    ctx.progress(0.02, "reading anchors, labels and constraints")
    data = _training_data(ctx, params, classes)
    if data.samples.shape[1:] != (meta.sample_config.channels, meta.sample_config.size, meta.sample_config.size):
        raise Conflict(
            f"sequence {params.sequence_id} has samples {data.samples.shape[1:]}, model {parent_id} expects "
            f"({meta.sample_config.channels}, {meta.sample_config.size}, {meta.sample_config.size})"
        )
    cfg = finetune_job_config(params)
    out_dir = model_versions.model_dir(ctx.settings, "finetune", ctx.job_id)

    def on_progress(p: Any) -> None:
        msg = f"epoch {p.epoch + 1}/{p.epochs} step {p.step}/{p.steps_per_epoch} loss {p.loss:.3f}"
        ctx.progress(0.05 + 0.9 * p.fraction, msg)

    def stop() -> bool:
        return ctx.cancelled.is_set() or ctx.lease_lost.is_set()

    ctx.progress(0.05, f"fine-tuning on {len(data.labelled)} labelled samples and {len(data.pairs)} pairs")
    res = finetune((model, meta), data, cfg, checkpoint_dir=out_dir, report=on_progress, stop=stop, parent=parent_path)
    ctx.checkpoint()
    if res.checkpoint is None:
        raise Invalid("fine-tuning finished no epoch")
    metrics = dict(res.metrics) | {"sequence_id": params.sequence_id, "constraints": params.constraints}
    predict_job_id = None
    with ctx.db.write() as s:
        mv = model_versions.register_model_version(
            s,
            name=params.name or f"{parent_name} + finetune seq {params.sequence_id}",
            kind="finetune",
            path=res.checkpoint.resolve(),
            metrics=metrics,
            config={"training": cfg.model_dump(mode="json"), "params": params.model_dump(mode="json")},
            parent_id=parent_id,
            job_id=ctx.job_id,
            created_by_id=ctx.user_id,
        )
        mv_id = mv.id
        s.commit()
    predict_error = None
    if params.predict and not _created_by_admin(ctx):
        # queued before the policy refused it for operators: predict stays an admin's decision
        predict_error = "predict needs the admin role"
    elif params.predict:
        try:
            with ctx.db.write() as s:
                predict_job_id = _queue_predict(s, params.sequence_id, mv_id, ctx.user_id)
                s.commit()
        except (ServiceError, ValidationError) as exc:  # the model stays registered
            predict_error = str(getattr(exc, "detail", exc))
    return {
        "model_id": mv_id,
        "parent_model_id": parent_id,
        "path": str(res.checkpoint.resolve()),
        "labelled": int(len(np.unique(data.labelled))),
        "pairs": int(len(data.pairs)),
        "anchors_per_class": metrics.get("anchors_per_class"),
        "predict_job_id": predict_job_id,
        "predict_error": predict_error,
    }


def _created_by_admin(ctx: JobContext) -> bool:
    from app.crud.users import user_role

    with ctx.db.read() as s:
        return user_role(s, ctx.user_id) == "admin"


def _queue_predict(s: Any, sequence_id: int, model_version_id: int, user_id: int | None) -> int:
    from app import crud

    try:
        jt = get_job_type("predict")
    except KeyError:
        raise Invalid("no `predict` job type is registered on this worker") from None
    params = jt.params.model_validate({"sequence_id": sequence_id, "model_id": model_version_id})
    if jt.prepare is not None:
        jt.prepare(s, params)
    return crud.create_job(s, "predict", params.model_dump(mode="json"), user_id).id


register(
    JobType(
        name="finetune",
        params=FinetuneParams,
        handler=run_finetune,
        admin_only=False,
        description="Fine-tune a model on a sequence's confirmed anchors and constraints; register it; optionally predict.",
        prepare=prepare_finetune,
        # operators: a bounded run on the shared worker (every numeric param; a step at most
        # 128 labels x (1 + 2 x 4) canvases), and no predict (it rewrites every track's predicted
        # class, an admin decision)
        operator_rule=OperatorRule(
            max_values={"epochs": 50, "steps_per_epoch": 1000, "batch_labelled": 128, "pairs_per_label": 4, "threads": 8,
                        "min_score": 1.0, "gamma": 1.0, "lr": 0.1, "balance_weight": 10.0, "seed": 2**31 - 1},
            admin_switches=("predict",),
        ),
        max_run_seconds=3600.0,
    )
)
