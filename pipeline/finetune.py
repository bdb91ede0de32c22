"""Fine-tuning a pretrained model on a new scene: confirmed anchors plus the scene's constraints.

Step 6 of the method (Mei et al., Table 10): the pretrained model (constraint100 in the paper)
keeps training, with the paper's loss, on

- the anchors the operator confirmed or corrected (labelled samples; a confirmed track-level
  anchor contributes every sample of its track), and
- the new scene's must-link constraints: `verified` ones (pairs of tracks an operator accepted,
  weight 1, the paper), or `automatic` ones (every association link, weighted by its score),
  or `none`.

The training loop is `pipeline.training.train` started from the pretrained weights, with the
training defaults changed for few anchors by `TrainingConfig.finetuning` (800 steps, batches of
16 anchors + 32 pairs, no label closure). `balance` repeats the anchors of rare classes so batches draw classes evenly: a confirmed
track labels all its samples, and without it a few long bush tracks outweigh every person. On the
simulated new scene this took fine-tuning from below the pretrained model to near baseline_max
(README "Fine-tuning on a new scene"). Without a validation set the paper's selection rule takes
the last epoch whose training loss is below the threshold.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np

from pipeline.classes import SAMPLE_CLASSES
from pipeline.config import TrainingConfig
from pipeline.errors import ConfigError, DataError
from pipeline.metrics import ClassificationReport
from pipeline.model import CheckpointMeta, SampleCNN, load_checkpoint, save_checkpoint
from pipeline.progress import QUIET, Progress
from pipeline.training import LabelledSamples, TrainingData, TrainProgress, evaluate, train

ConstraintMode = Literal["verified", "automatic", "none"]
CONSTRAINT_MODES: tuple[str, ...] = ("verified", "automatic", "none")



def finetune_data(
    samples: np.ndarray,
    anchor_index: np.ndarray,
    anchor_labels: np.ndarray,
    pairs: np.ndarray | None = None,
    pair_scores: np.ndarray | None = None,
    pair_verified: np.ndarray | None = None,
    constraints: str = "verified",
    replay: LabelledSamples | None = None,
    balance: bool = False,
) -> TrainingData:
    """The fine-tuning pool of a new scene.

    samples:       (M, C, S, S) uint8 canvases of the new scene.
    anchor_index:  (A,) int64 indices into `samples` of the confirmed anchors (duplicates are
                   dropped, the first label wins); anchor_labels (A,) their class ids.
    pairs:         (P, 2) int64 constraint pairs into `samples`; pair_scores (P,) association
                   scores; pair_verified (P,) bool whether an operator accepted the pair's track.
    constraints:   verified (verified pairs, weight 1), automatic (all pairs, weight = score
                   clipped to [0, 1]) or none.
    replay:        labelled samples of the pretraining data to keep training on (against
                   forgetting); appended after `samples`.
    balance:       repeat labelled samples so every present class is drawn equally often
                   (`balance_classes`).
    """
    if constraints not in CONSTRAINT_MODES:
        raise ConfigError(f"constraints must be one of {', '.join(CONSTRAINT_MODES)}, got {constraints!r}")
    idx = np.asarray(anchor_index, np.int64)
    lab = np.asarray(anchor_labels, np.int64)
    if idx.shape != lab.shape:
        raise DataError(None, f"anchor_index {idx.shape} and anchor_labels {lab.shape} differ")
    _, first = np.unique(idx, return_index=True)
    idx, lab = idx[np.sort(first)], lab[np.sort(first)]
    pr = np.zeros((0, 2), np.int64) if pairs is None else np.asarray(pairs, np.int64).reshape(-1, 2)
    score = np.ones(len(pr), np.float32) if pair_scores is None else np.asarray(pair_scores, np.float32)
    ver = np.ones(len(pr), bool) if pair_verified is None else np.asarray(pair_verified, bool)
    if score.shape != (len(pr),) or ver.shape != (len(pr),):
        raise DataError(None, f"pair_scores {score.shape} / pair_verified {ver.shape} do not match {len(pr)} pairs")
    if constraints == "none":
        pr, w = pr[:0], score[:0]
    elif constraints == "verified":
        pr, w = pr[ver], np.ones(int(ver.sum()), np.float32)
    else:
        w = np.clip(np.nan_to_num(score, nan=0.0), 0.0, 1.0)
        keep = w > 0
        pr, w = pr[keep], w[keep]
    if replay is not None and len(replay):
        # labelled samples of the pretraining data, appended after the scene's samples
        idx = np.concatenate([idx, len(samples) + np.arange(len(replay))])
        lab = np.concatenate([lab, np.asarray(replay.labels, np.int64)])
        samples = np.concatenate([samples, replay.samples])
    if balance and len(lab):
        idx, lab = balance_classes(idx, lab)
    return TrainingData.build(samples, idx, lab, pr, w)


def balance_classes(index: np.ndarray, labels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Repeat the labelled samples of each class (whole copies, then the first ones) until every
    present class has as many entries as the largest: batches then draw classes evenly, so a
    confirmed car track of 200 samples does not drown a person track of 10."""
    counts = np.bincount(labels)
    top = counts.max()
    out_i, out_y = [], []
    for k in np.flatnonzero(counts):
        members = index[labels == k]
        reps = np.resize(members, top)  # cycles through the members
        out_i.append(reps)
        out_y.append(np.full(top, k, np.int64))
    return np.concatenate(out_i), np.concatenate(out_y)


@dataclass(frozen=True)
class FinetuneResult:
    """model: the fine-tuned model (eval mode); checkpoint: `best.pt` when a folder was given."""

    model: SampleCNN
    meta: CheckpointMeta
    metrics: dict[str, Any]
    checkpoint: Path | None
    val_report: ClassificationReport | None = None
    history: list[Any] = field(default_factory=list)
    cancelled: bool = False


def finetune(
    pretrained: str | Path | tuple[SampleCNN, CheckpointMeta],
    data: TrainingData,
    config: TrainingConfig | None = None,
    val: LabelledSamples | None = None,
    checkpoint_dir: str | Path | None = None,
    progress: Progress = QUIET,
    report: Callable[[TrainProgress], None] | None = None,
    stop: Callable[[], bool] | None = None,
    parent: str | None = None,
) -> FinetuneResult:
    """Fine-tune `pretrained` (a checkpoint path, or a loaded model and its meta) on `data`.

    config: the full TrainingConfig to use; None = `TrainingConfig().finetuning()`.
    val: optional labelled samples of the new scene for the paper's model selection and metrics.
    checkpoint_dir: where to write `best.pt` (self-describing; its metrics name the parent).
    parent: recorded in the metrics as the parent model (default: the checkpoint path).
    """
    if isinstance(pretrained, str | Path):
        model, meta = load_checkpoint(pretrained)
        parent = parent or str(pretrained)
    else:
        model, meta = pretrained
    if len(data.labelled) == 0 and len(data.pairs) == 0:
        raise DataError(None, "nothing to fine-tune on: no confirmed anchors and no constraints")
    if len(data.labelled) == 0:
        # The paper's "unsupervised" attempt: constraints alone collapse onto one class.
        raise DataError(None, "fine-tuning needs at least one confirmed anchor (constraints alone collapse)")
    cfg = config or TrainingConfig().finetuning()
    k = meta.model_config.num_classes
    classes = tuple(meta.classes[:k]) if meta.classes else tuple(SAMPLE_CLASSES[:k])
    result = train(
        data,
        cfg,
        meta.model_config,
        meta.sample_config,
        val=val,
        checkpoint_dir=None,
        init_model=model,
        progress=progress,
        report=report,
        stop=stop,
        classes=classes,
        label_set=meta.label_set,
    )
    _, first = np.unique(data.labelled, return_index=True)  # balancing repeats samples
    anchors_per_class = np.bincount(data.labels[first], minlength=k)
    metrics: dict[str, Any] = dict(result.metrics)
    metrics["kind"] = "finetune"
    metrics["parent"] = parent
    metrics["anchors_per_class"] = {classes[i]: int(anchors_per_class[i]) for i in range(k)}
    metrics["pairs"] = int(len(data.pairs))
    metrics["pairs_weighted"] = bool(np.any(data.pair_weights != 1.0))
    if val is not None and len(val):
        metrics["val"] = evaluate(result.model, val, cfg.eval_batch, classes).to_dict()
    ckpt = None
    if checkpoint_dir is not None and result.selected_epoch >= 0:
        ckpt = save_checkpoint(
            Path(checkpoint_dir) / "best.pt", result.model, meta.model_config, meta.sample_config, metrics, cfg, classes,
            input_stats=meta.input_stats, label_set=meta.label_set,
        )
    new_meta = CheckpointMeta(meta.net, meta.model_config, meta.sample_config, classes, metrics, cfg, meta.input_stats,
                              meta.label_set)
    return FinetuneResult(result.model, new_meta, metrics, ckpt, result.val_report, result.history, result.cancelled)
