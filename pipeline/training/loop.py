"""The training loop: epochs of steps, the learning-rate schedule, the paper's model selection and the
checkpoints it writes."""

from __future__ import annotations

import copy
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch

from pipeline.classes import SAMPLE_CLASSES
from pipeline.config import ModelConfig, SampleConfig, TrainingConfig
from pipeline.errors import ConfigError, DataError
from pipeline.input_stats import canvas_stats
from pipeline.label_sets import DEFAULT_LABEL_SET
from pipeline.metrics import ClassificationReport, classification_report
from pipeline.model import (
    NetConfig,
    SampleCNN,
    build_model,
    predict,
    resolve_device,
    save_checkpoint,
    to_input,
)
from pipeline.progress import QUIET, Progress
from pipeline.training.augment import augment_batch, vary_intensity
from pipeline.training.data import LabelledSamples, TrainingData, seed_everything
from pipeline.training.loss import LossParts, semi_supervised_loss
from pipeline.training.plots import write_training_plots
from pipeline.training.sampling import (
    _BatchDraw,
    _closure,
)


@dataclass(frozen=True)
class TrainProgress:
    """Reported to the progress callback every few steps and after each epoch."""

    epoch: int  # 0-based
    epochs: int
    step: int  # steps done in this epoch
    steps_per_epoch: int
    loss: float  # running mean training loss of this epoch
    val_f: float | None = None  # set on the epoch-end report when a validation set is given
    epoch_done: bool = False

    @property
    def fraction(self) -> float:
        return (self.epoch * self.steps_per_epoch + self.step) / max(self.epochs * self.steps_per_epoch, 1)


@dataclass(frozen=True)
class EpochRecord:
    epoch: int
    loss: float  # mean total loss over the epoch's steps
    loss_labelled: float
    loss_constraint: float
    loss_balance: float
    val_f: float  # NaN without a validation set
    seconds: float
    samples_per_s: float  # canvases through forward + backward per second


@dataclass(frozen=True)
class TrainResult:
    """model: the selected model (eval mode); history: one record per finished epoch."""

    model: SampleCNN
    history: list[EpochRecord]
    selected_epoch: int  # index into history, -1 when no epoch finished
    selection: str  # "val_f_below_threshold" | "lowest_loss" | "last_below_threshold" | "none"
    val_report: ClassificationReport | None
    checkpoint: Path | None
    cancelled: bool = False
    metrics: dict[str, Any] = field(default_factory=dict)
    input_stats: dict[str, Any] = field(default_factory=dict)  # of the training canvases (pipeline.input_stats)

    @property
    def train_loss(self) -> np.ndarray:
        return np.array([r.loss for r in self.history])

    @property
    def val_f(self) -> np.ndarray:
        return np.array([r.val_f for r in self.history])


def evaluate(model: SampleCNN, data: LabelledSamples, batch: int = 256,
             classes: tuple[str, ...] | None = None) -> ClassificationReport:
    """Per-class precision/recall/F of the model's arg-max on labelled samples; `classes`: the names
    of its outputs (None: the default label set's)."""
    pred = predict(model, data.samples, batch).argmax(axis=1)
    k = model.config.num_classes
    return classification_report(data.labels, pred, k, _class_names(classes, k))


def _class_names(classes: tuple[str, ...] | None, k: int) -> tuple[str, ...]:
    """The names of a model's `k` outputs: `classes` (ConfigError unless there are `k`), or the
    default label set's (pipeline.classes) when None."""
    if classes is None:
        return tuple(SAMPLE_CLASSES[:k])
    if len(classes) != k:
        raise ConfigError(f"model.num_classes is {k} but the label set has {len(classes)} classes ({', '.join(classes)})")
    return tuple(classes)


def learning_rate(config: TrainingConfig, step: int, total_steps: int) -> float:
    """The learning rate at `step` of `total_steps`: constant, or cosine from config.lr to 0."""
    if config.lr_schedule == "cosine":
        return config.lr * 0.5 * (1.0 + math.cos(math.pi * min(step, total_steps) / max(total_steps, 1)))
    return config.lr


def _select(history: list[EpochRecord], threshold: float) -> tuple[int, str]:
    if not history:
        return -1, "none"
    loss = np.array([r.loss for r in history])
    vf = np.array([r.val_f for r in history])
    below = loss < threshold
    if below.any():
        if np.isfinite(vf[below]).any():
            cand = np.flatnonzero(below & np.isfinite(vf))
            return int(cand[np.argmax(vf[cand])]), "val_f_below_threshold"
        return int(np.flatnonzero(below)[-1]), "last_below_threshold"
    return int(np.argmin(loss)), "lowest_loss"


def train(
    data: TrainingData,
    config: TrainingConfig,
    model_config: ModelConfig,
    sample_config: SampleConfig,
    val: LabelledSamples | None = None,
    checkpoint_dir: str | Path | None = None,
    init_model: SampleCNN | None = None,
    progress: Progress = QUIET,
    report: Callable[[TrainProgress], None] | None = None,
    stop: Callable[[], bool] | None = None,
    classes: tuple[str, ...] | None = None,
    label_set: str = DEFAULT_LABEL_SET,
) -> TrainResult:
    """Train the CNN on labels + constraints; return the model chosen by the paper's rule.

    init_model: start from these weights (fine-tuning); else a fresh network from the configs.
    checkpoint_dir: when given, the selected model is written there as `best.pt` and the last
        epoch as `last.pt` (each a self-describing checkpoint, see `pipeline.model`).
    progress: a step bar (`pipeline.progress`); report: a callback receiving `TrainProgress`
        every few steps and after each epoch (the jobs write it into their row).
    stop: polled every step; returning True ends training early (`cancelled=True`), keeping the
        best epoch so far.
    classes, label_set: the names of the model's outputs and the label set they come from, written
        into the checkpoints (None: the default set's); as many as `model_config.num_classes`.
    config.threads > 0 sets torch's CPU threads for the run (restored afterwards).
    """
    names = _class_names(classes, model_config.num_classes)
    num_l, num_p = len(data.labelled), len(data.pairs)
    if num_l == 0 and num_p == 0:
        raise DataError(None, "training data holds neither labels nor pairs")
    k = model_config.num_classes
    if num_l and (data.labels.min() < 0 or data.labels.max() >= k):
        raise DataError(None, f"labels: class ids outside 0..{k - 1}")
    if data.samples.shape[1:] != (sample_config.channels, sample_config.size, sample_config.size):
        raise ConfigError(
            f"samples are {data.samples.shape[1:]}, sample config says "
            f"({sample_config.channels}, {sample_config.size}, {sample_config.size})"
        )
    if config.batch_labelled < 1 or config.pairs_per_label < 0:
        raise ConfigError("training.batch_labelled must be >= 1 and training.pairs_per_label >= 0")

    annotations: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
    if config.closure_labels and num_l and num_p:
        lab, y, _, group = _closure(data.labelled, data.labels, data.pairs, len(data.samples))
        if config.closure_draw == "annotation":  # (positions of the annotations, their labels, groups)
            annotations = (np.searchsorted(lab, data.labelled), data.labels, group)
        data = TrainingData(data.samples, lab, y, data.pairs, data.pair_weights)
    threads_before = torch.get_num_threads()
    if config.threads:
        torch.set_num_threads(config.threads)
    try:
        return _train(data, config, model_config, sample_config, val, checkpoint_dir, init_model, progress, report, stop,
                      annotations, (names, label_set))
    finally:
        torch.set_num_threads(threads_before)


class _Stepper:
    """One optimisation step on a drawn batch; the training pool is kept on the device."""

    def __init__(self, model: SampleCNN, data: TrainingData, config: TrainingConfig, sample_config: SampleConfig,
                 device: torch.device, total_steps: int) -> None:
        self.model, self.config, self.device, self.total_steps = model, config, device, total_steps
        self.opt = torch.optim.AdamW(model.parameters(), lr=config.lr, weight_decay=config.weight_decay)
        self.gen = torch.Generator().manual_seed(config.seed)
        self.samples = torch.from_numpy(data.samples).to(device)  # (M, C, S, S) uint8
        self.labels = torch.from_numpy(data.labels).to(device)  # (L,)
        self.weights = torch.from_numpy(data.pair_weights).to(device)  # (P,)
        self.use_weights = config.weighted_pairs and bool(np.any(data.pair_weights != 1.0))
        self.max_shift = int(round(config.augment_shift * sample_config.size)) if config.augment else 0

    def __call__(self, li: np.ndarray, pi: np.ndarray, idx: np.ndarray, global_step: int) -> LossParts:
        m, cfg = len(li), self.config
        x = to_input(self.samples[torch.from_numpy(idx).to(self.device)])  # (m + 2n, C, S, S)
        if cfg.augment:
            x = augment_batch(x, self.max_shift, self.gen, cfg.augment_erase)
        if cfg.intensity_drop > 0 or cfg.intensity_gamma > 0:
            x = vary_intensity(x, cfg.intensity_drop, cfg.intensity_gamma, self.gen)
        logits = self.model(x)  # (m + 2n, K)
        pw = self.weights[torch.from_numpy(pi).to(self.device)] if self.use_weights else None  # (n,)
        parts = semi_supervised_loss(logits[:m], self.labels[torch.from_numpy(li).to(self.device)],
                                     logits[m : m + len(pi)], logits[m + len(pi) :], gamma=cfg.gamma,
                                     pair_weights=pw, balance_weight=cfg.balance_weight,
                                     constraint_loss=cfg.constraint_loss)
        if not torch.isfinite(parts.total):
            raise ConfigError(f"training diverged (loss {float(parts.total)}) at step {global_step}; lower training.lr")
        if cfg.lr_schedule != "constant":
            for g in self.opt.param_groups:
                g["lr"] = learning_rate(cfg, global_step, self.total_steps)
        self.opt.zero_grad(set_to_none=True)
        parts.total.backward()
        self.opt.step()
        return parts


@dataclass
class _EpochRun:
    sums: np.ndarray  # (4,) summed total, labelled, constraint and balance losses
    seen: int  # canvases through the network
    done: int  # steps run
    cancelled: bool


def _run_epoch(epoch: int, draw: _BatchDraw, step_fn: _Stepper, config: TrainingConfig, bar: Any,
               report: Callable[[TrainProgress], None] | None, stop: Callable[[], bool] | None) -> _EpochRun:
    run = _EpochRun(np.zeros(4), 0, 0, False)
    every = max(1, draw.steps // 10)
    step_fn.model.train()
    for step in range(draw.steps):
        if stop is not None and stop():
            run.cancelled = True
            break
        li, pi, idx = draw.draw()
        parts = step_fn(li, pi, idx, epoch * draw.steps + step)
        run.sums += [parts.total.item(), parts.labelled.item(), parts.constraint.item(), parts.balance.item()]
        run.seen += len(idx)
        run.done = step + 1
        bar.update()
        if report is not None and run.done % every == 0 and run.done < draw.steps:
            report(TrainProgress(epoch, config.epochs, run.done, draw.steps, run.sums[0] / run.done))
    return run


@dataclass
class _Selection:
    """The epochs so far and the weights of the one the paper's rule currently selects."""

    history: list[EpochRecord] = field(default_factory=list)
    state: dict[str, torch.Tensor] | None = None
    report: ClassificationReport | None = None

    def add(self, rec: EpochRecord, model: SampleCNN, val_report: ClassificationReport | None, threshold: float) -> None:
        self.history.append(rec)
        # The final choice is always an epoch that was the choice when it finished, so one copy
        # of the weights suffices.
        if _select(self.history, threshold)[0] == rec.epoch:
            self.state = {k: v.detach().clone() for k, v in model.state_dict().items()}
            self.report = val_report


def _train(
    data: TrainingData,
    config: TrainingConfig,
    model_config: ModelConfig,
    sample_config: SampleConfig,
    val: LabelledSamples | None,
    checkpoint_dir: str | Path | None,
    init_model: SampleCNN | None,
    progress: Progress,
    report: Callable[[TrainProgress], None] | None,
    stop: Callable[[], bool] | None,
    annotations: tuple[np.ndarray, np.ndarray, np.ndarray] | None,
    outputs: tuple[tuple[str, ...], str],  # (class names, label set name)
) -> TrainResult:
    classes, label_set = outputs
    seed_everything(config.seed)
    device = resolve_device(config.device)
    rng = np.random.default_rng(config.seed)
    net = NetConfig.from_configs(model_config, sample_config)
    model = copy.deepcopy(init_model) if init_model is not None else build_model(net)
    if model.config != net:
        raise ConfigError(f"init model {model.config} does not match configs {net}")
    model.to(device).train()
    draw = _BatchDraw(data, config, annotations, rng)
    step_fn = _Stepper(model, data, config, sample_config, device, max(config.epochs * draw.steps, 1))

    chosen = _Selection()
    cancelled = False
    with progress.bar(config.epochs * draw.steps, "train", unit="step", leave=False) as bar:
        for epoch in range(config.epochs):
            t0 = time.perf_counter()
            run = _run_epoch(epoch, draw, step_fn, config, bar, report, stop)
            cancelled = run.cancelled
            if run.done == 0:
                break
            val_report = evaluate(model, val, config.eval_batch, classes) if val is not None and len(val) else None
            val_f = val_report.mean_f if val_report is not None else float("nan")
            seconds = time.perf_counter() - t0
            rec = EpochRecord(epoch, *map(float, run.sums / run.done), val_f, seconds, run.seen / max(seconds, 1e-9))
            chosen.add(rec, model, val_report, config.loss_threshold)
            if report is not None:
                report(TrainProgress(epoch, config.epochs, run.done, draw.steps, rec.loss, val_f, epoch_done=True))
            bar.set_postfix(loss=f"{rec.loss:.3f}", val_f=f"{val_f:.1f}")
            if cancelled:
                break
    metrics = {"num_labelled": len(data.labelled), "num_pairs": len(data.pairs), "device": str(device)}
    stats = canvas_stats(data.samples, config.seed)
    return _finish(model, net, chosen, cancelled, metrics, config, model_config, sample_config, checkpoint_dir, stats,
                   outputs)


def _finish(model: SampleCNN, net: NetConfig, chosen: _Selection, cancelled: bool, metrics: dict[str, Any],
            config: TrainingConfig, model_config: ModelConfig, sample_config: SampleConfig,
            checkpoint_dir: str | Path | None, stats: dict[str, Any],
            outputs: tuple[tuple[str, ...], str]) -> TrainResult:
    """Load the selected epoch's weights, gather the metrics, write best.pt / last.pt (naming the
    outputs' classes and label set) and plots."""
    classes, label_set = outputs
    history = chosen.history
    selected, how = _select(history, config.loss_threshold)
    last_state = None
    if selected >= 0:
        assert chosen.state is not None
        if selected != len(history) - 1:
            last_state = {k: v.detach().clone() for k, v in model.state_dict().items()}
        model.load_state_dict(chosen.state)
    model.eval()
    metrics = {
        "selected_epoch": selected,
        "selection": how,
        "epochs_run": len(history),
        "cancelled": cancelled,
        "train_loss": [r.loss for r in history],
        "val_f": [None if math.isnan(r.val_f) else r.val_f for r in history],
        "samples_per_s": float(np.mean([r.samples_per_s for r in history])) if history else None,
    } | metrics
    if chosen.report is not None:
        metrics["val"] = chosen.report.to_dict()
    ckpt = None
    if checkpoint_dir is not None and selected >= 0:
        out = Path(checkpoint_dir)
        ckpt = save_checkpoint(out / "best.pt", model, model_config, sample_config, metrics, config, classes,
                               input_stats=stats, label_set=label_set)
        last = model
        if last_state is not None:
            last = build_model(net)
            last.load_state_dict(last_state)
        save_checkpoint(out / "last.pt", last, model_config, sample_config, {"epoch": len(history) - 1}, config,
                        classes, input_stats=stats, label_set=label_set)
        write_training_plots(out, history, selected, chosen.report, config.loss_threshold)
    return TrainResult(model, history, selected, how, chosen.report, ckpt, cancelled, metrics, stats)
