"""Semi-supervised training of the sample CNN on labels plus must-link constraints (Mei et al.).

The loss is the paper's, Eq. (8):

    L   = L_l + L_c
    L_l = -1/M sum_i ln P_{y_i}(x_i)                        (mean cross-entropy, M labelled samples)
    L_c = gamma/N sum_n w_n (1 - sum_k P_k(x_i) P_k(x_j))   (N constraint pairs, gamma in [0, 1])

with w_n = 1 for verified pairs (the paper). Extensions (`TrainingConfig`'s defaults say which are on):
- `weighted_pairs` with pair weights < 1: automatic constraints weighted by their association score;
- `balance_weight` b > 0 adds b (ln K - H(mean_b P(x_b))) over the pair samples: maximising the
  entropy of the batch-mean prediction keeps constraints-only training from collapsing onto one
  class (the paper reports everything becoming "trunk").
- `transitive_pairs`: must-link is an equivalence, so the right side of each drawn pair is any
  other sample of the left side's track (its component in the pair graph), not only the next
  frame's: pairs then join near and far, whole and occluded views of one object;
- `closure_labels`: must-link is an equivalence, so a label holds for its whole component of
  the pair graph; every member of a component with a labelled sample is trained on that label
  (the labelled cross-entropy then draws from the closure; a component whose labelled samples
  disagree, possible only with unverified pairs, keeps just its own labels). The product's
  track review does the same: one click labels every sample of a track;
- `closure_draw="annotation"` (with closure labels): each labelled draw picks one of the given
  annotations, then a member of its component, so every annotation weighs as it does without
  constraints; "sample" draws the closure's samples alike, which weighs an annotation by the
  size of its component;
- `lr_schedule="cosine"`: the learning rate falls from lr to 0 over the run, so the last epochs,
  among which the selection rule picks, move less than a constant rate lets them.

With `balanced_labels` each batch draws its labelled samples class-uniformly (the labels of a rare
class are seen as often as those of a common one); without, uniformly, as the paper.

Each step holds m labelled samples and n = pairs_per_label * m pairs, run as one siamese forward
over [labelled; pair left sides; pair right sides]. M = 0 (constraints only) and N = 0 (labels
only) are the degenerate cases. Model selection follows the paper: the best validation F among
the epochs whose training loss is below `loss_threshold`, else the epoch of lowest loss.
"""

from __future__ import annotations

import copy
import math
import random
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F

from pipeline.classes import SAMPLE_CLASSES
from pipeline.config import ModelConfig, SampleConfig, TrainingConfig
from pipeline.errors import ConfigError, DataError
from pipeline.input_stats import canvas_stats
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

__all__ = [
    "LabelledSamples",
    "LossParts",
    "closure_labels",
    "erase_rectangles",
    "must_link_components",
    "TrainingData",
    "TrainProgress",
    "TrainResult",
    "evaluate",
    "predict",
    "seed_everything",
    "semi_supervised_loss",
    "split_by_group",
    "train",
]


def seed_everything(seed: int) -> None:
    """The one seed helper: Python, numpy and torch (CPU and CUDA), deterministic cuDNN."""
    random.seed(seed)
    np.random.seed(seed % 2**32)  # noqa: NPY002 - seeds code that uses the global numpy RNG
    torch.manual_seed(seed)
    torch.cuda.manual_seed_all(seed)
    torch.backends.cudnn.deterministic = True
    torch.backends.cudnn.benchmark = False


@dataclass(frozen=True)
class LabelledSamples:
    """samples: (M, C, S, S) uint8 canvases; labels: (M,) int64 class ids 0..K-1."""

    samples: np.ndarray
    labels: np.ndarray

    def __post_init__(self) -> None:
        assert self.samples.ndim == 4 and self.samples.dtype == np.uint8, (self.samples.dtype, self.samples.shape)
        assert self.labels.shape == (len(self.samples),), (self.labels.shape, len(self.samples))

    def __len__(self) -> int:
        return len(self.samples)


@dataclass(frozen=True)
class TrainingData:
    """The training pool: canvases, which of them are labelled, and must-link pairs among them.

    samples:      (M, C, S, S) uint8 canvases.
    labelled:     (L,) int64 indices into `samples` of the labelled samples.
    labels:       (L,) int64 class id (0..K-1) of each labelled sample.
    pairs:        (P, 2) int64 indices into `samples`: must-link constraints.
    pair_weights: (P,) float32 weight per pair: 1.0 verified, the association score for automatic pairs.
    """

    samples: np.ndarray
    labelled: np.ndarray
    labels: np.ndarray
    pairs: np.ndarray
    pair_weights: np.ndarray

    def __post_init__(self) -> None:
        m = len(self.samples)
        assert self.samples.ndim == 4 and self.samples.dtype == np.uint8, (self.samples.dtype, self.samples.shape)
        assert self.labelled.ndim == 1 and self.labels.shape == self.labelled.shape, (
            self.labelled.shape,
            self.labels.shape,
        )
        assert self.pairs.ndim == 2 and self.pairs.shape[1] == 2, self.pairs.shape
        assert self.pair_weights.shape == (len(self.pairs),), (self.pair_weights.shape, self.pairs.shape)
        for name, idx in (("labelled", self.labelled), ("pairs", self.pairs)):
            if idx.size and (idx.min() < 0 or idx.max() >= m):
                raise DataError(None, f"{name}: indices outside 0..{m - 1}")

    @classmethod
    def build(
        cls,
        samples: np.ndarray,
        labelled: np.ndarray | None = None,
        labels: np.ndarray | None = None,
        pairs: np.ndarray | None = None,
        pair_weights: np.ndarray | None = None,
    ) -> TrainingData:
        """Coerce dtypes; missing parts are empty (no labels / no pairs), pair weights default to 1."""
        lab = np.zeros(0, np.int64) if labelled is None else np.asarray(labelled, np.int64)
        y = np.zeros(0, np.int64) if labels is None else np.asarray(labels, np.int64)
        pr = np.zeros((0, 2), np.int64) if pairs is None else np.asarray(pairs, np.int64).reshape(-1, 2)
        w = np.ones(len(pr), np.float32) if pair_weights is None else np.asarray(pair_weights, np.float32)
        return cls(np.ascontiguousarray(samples), lab, y, pr, w)

    @classmethod
    def labelled_only(cls, data: LabelledSamples) -> TrainingData:
        return cls.build(data.samples, np.arange(len(data)), data.labels)


@dataclass(frozen=True)
class LossParts:
    """Scalar tensors: total = labelled + constraint + balance (each 0 when its part is empty/off)."""

    total: torch.Tensor
    labelled: torch.Tensor
    constraint: torch.Tensor
    balance: torch.Tensor


def semi_supervised_loss(
    logits_labelled: torch.Tensor,
    labels: torch.Tensor,
    logits_i: torch.Tensor,
    logits_j: torch.Tensor,
    gamma: float,
    pair_weights: torch.Tensor | None = None,
    balance_weight: float = 0.0,
    constraint_loss: str = "paper",
) -> LossParts:
    """The paper's L = L_l + L_c, plus the optional class-balance term.

    logits_labelled: (m, K) of the labelled samples, labels (m,) int64; m may be 0.
    logits_i, logits_j: (n, K) of the two sides of the n pairs; n may be 0.
    pair_weights: (n,) w_n, None = all 1 (the paper).
    constraint_loss: "paper" (1 - P_i . P_j) or "squared" (1/2 |P_i - P_j|^2, `TrainingConfig`).
    """
    m, n = len(logits_labelled), len(logits_i)
    if m == 0 and n == 0:
        raise ValueError("a batch needs labelled samples or pairs")
    zero = (logits_labelled if m else logits_i).new_zeros(())
    l_l = F.cross_entropy(logits_labelled, labels) if m else zero
    l_c, l_b = zero, zero
    if n:
        p_i = torch.softmax(logits_i, dim=1)  # (n, K)
        p_j = torch.softmax(logits_j, dim=1)  # (n, K)
        if constraint_loss == "squared":
            disagree = 0.5 * (p_i - p_j).square().sum(dim=1)  # (n,)
        else:
            disagree = 1.0 - (p_i * p_j).sum(dim=1)  # (n,) P(y_i != y_j)
        if pair_weights is not None:
            disagree = disagree * pair_weights
        l_c = gamma * disagree.sum() / n
        if balance_weight > 0:
            p_mean = torch.cat([p_i, p_j]).mean(dim=0)  # (K,) batch-mean prediction
            entropy = -(p_mean * torch.log(p_mean.clamp_min(1e-12))).sum()
            l_b = balance_weight * (math.log(p_mean.numel()) - entropy)
    return LossParts(l_l + l_c + l_b, l_l, l_c, l_b)


def augment_batch(x: torch.Tensor, max_shift: int, generator: torch.Generator, erase: float = 0.0) -> torch.Tensor:
    """Random horizontal flip and integer shifts (zero fill) of each canvas in (B, C, S, S); with
    `erase` > 0, that share of the canvases also loses one random rectangle (`erase_rectangles`)."""
    b, _, s, _ = x.shape
    dev = x.device
    flip = torch.rand(b, generator=generator) < 0.5
    x = torch.where(flip.to(dev)[:, None, None, None], x.flip(3), x)
    if erase > 0:
        x = erase_rectangles(x, erase, generator)
    if max_shift <= 0:
        return x
    shifts = torch.randint(-max_shift, max_shift + 1, (2, b), generator=generator).to(dev)  # (2, B)
    padded = F.pad(x, (max_shift,) * 4)  # (B, C, S + 2 pad, S + 2 pad)
    base = torch.arange(s, device=dev) + max_shift  # (S,)
    rows = base[None, :] - shifts[0][:, None]  # (B, S)
    cols = base[None, :] - shifts[1][:, None]  # (B, S)
    bi = torch.arange(b, device=dev)[:, None, None]  # (B, 1, 1)
    out = padded.permute(0, 2, 3, 1)[bi, rows[:, :, None], cols[:, None, :]]  # (B, S, S, C)
    return out.permute(0, 3, 1, 2)  # (B, C, S, S), stored NHWC: the network's channels_last, no copy


def vary_intensity(x: torch.Tensor, drop: float, gamma: float, generator: torch.Generator) -> torch.Tensor:
    """(B, C, S, S) float canvases in [0, 1] with the intensity channel (2) emptied in a `drop`
    share of them (a sensor without intensity: the geometry-only input) and raised to a random
    power 2^u, u uniform in [-gamma, gamma], in the others (another sensor's response to
    reflectivity)."""
    b = x.shape[0]
    keep = (torch.rand(b, generator=generator) >= drop).to(x.dtype)  # (B,)
    power = torch.pow(2.0, (torch.rand(b, generator=generator) * 2.0 - 1.0) * gamma)  # (B,)
    intensity = x[:, 2].clamp_min(0.0).pow(power.to(x.device)[:, None, None]) * keep.to(x.device)[:, None, None]
    return torch.cat([x[:, :2], intensity[:, None], x[:, 3:]], dim=1)


def erase_rectangles(x: torch.Tensor, share: float, generator: torch.Generator) -> torch.Tensor:
    """(B, C, S, S) with `share` of the canvases zeroed inside one random rectangle each, its
    sides a tenth to half of the canvas side (random erasing)."""
    b, _, s, _ = x.shape
    hit = torch.rand(b, generator=generator) < share  # (B,)
    size = (torch.rand(2, b, generator=generator) * 0.4 + 0.1) * s  # (2, B) rectangle height, width
    start = torch.rand(2, b, generator=generator) * (s - size)  # (2, B) top, left
    idx = torch.arange(s, dtype=torch.float32)  # (S,)
    inside = [(idx[None, :] >= start[k][:, None]) & (idx[None, :] < (start[k] + size[k])[:, None]) for k in (0, 1)]
    mask = inside[0][:, :, None] & inside[1][:, None, :] & hit[:, None, None]  # (B, S, S)
    return x.masked_fill(mask.to(x.device)[:, None], 0.0)


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


def evaluate(model: SampleCNN, data: LabelledSamples, batch: int = 256) -> ClassificationReport:
    """Per-class precision/recall/F of the model's arg-max on labelled samples."""
    pred = predict(model, data.samples, batch).argmax(axis=1)
    k = model.config.num_classes
    return classification_report(data.labels, pred, k, tuple(SAMPLE_CLASSES[:k]))


def split_by_group(
    labels: np.ndarray, groups: np.ndarray, val_fraction: float, seed: int | np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:
    """(train, val) int64 indices into `labels` (L,) whose samples belong to `groups` (L,): the
    track of each sample (the train job) or its ground-truth object (the simulated experiments,
    where an object's several tracks would otherwise land on both sides); `seed` may be a
    generator to draw from (its state advances).

    Whole groups go to one side: the samples of one track or object are near-duplicates, so a
    split of samples would validate on copies of training samples. Per class present,
    round(val_fraction x its groups) groups go to validation, never all of them; a group holding
    samples of several classes goes to validation when any of its classes sends it there.
    """
    rng = np.random.default_rng(seed)
    labels, groups = np.asarray(labels), np.asarray(groups)
    val_groups = []
    for k in np.unique(labels):
        cand = np.unique(groups[labels == k])
        cand = cand[rng.permutation(len(cand))]
        n_val = int(round(len(cand) * val_fraction))
        val_groups.append(cand[: min(n_val, max(len(cand) - 1, 0))])
    vg = np.concatenate(val_groups) if val_groups else np.zeros(0, groups.dtype)
    in_val = np.isin(groups, vg)
    return np.flatnonzero(~in_val).astype(np.int64), np.flatnonzero(in_val).astype(np.int64)


class _Cycler:
    """Endless shuffled passes over range(n), drawn in chunks."""

    def __init__(self, n: int, rng: np.random.Generator) -> None:
        self.n, self.rng = n, rng
        self.order = rng.permutation(n)
        self.pos = 0

    def take(self, k: int) -> np.ndarray:
        out = []
        while k > 0:
            if self.pos == self.n:
                self.order, self.pos = self.rng.permutation(self.n), 0
            chunk = self.order[self.pos : self.pos + k]
            out.append(chunk)
            self.pos += len(chunk)
            k -= len(chunk)
        return np.concatenate(out)


class _BalancedCycler:
    """Labelled positions drawn class-uniformly: each draw picks a class present at random, then the
    next of that class's own shuffled passes."""

    def __init__(self, labels: np.ndarray, rng: np.random.Generator) -> None:
        self.rng = rng
        self.members = [np.flatnonzero(labels == k) for k in np.unique(labels)]
        self.cyclers = [_Cycler(len(m), rng) for m in self.members]

    def take(self, k: int) -> np.ndarray:
        cls = self.rng.integers(0, len(self.members), k)  # (k,)
        out = np.empty(k, np.int64)
        for c in np.unique(cls):
            sel = np.flatnonzero(cls == c)
            out[sel] = self.members[c][self.cyclers[c].take(len(sel))]
        return out


def must_link_components(pairs: np.ndarray, num_samples: int) -> tuple[int, np.ndarray]:
    """(number of components, (num_samples,) component id) of the must-link graph."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(num_samples, num_samples))
    n_comp, comp = connected_components(graph, directed=False)
    return int(n_comp), comp


def _closure(
    labelled: np.ndarray, labels: np.ndarray, pairs: np.ndarray, num_samples: int
) -> tuple[np.ndarray, np.ndarray, int, np.ndarray]:
    """closure_labels' result plus (L',) a group id per output sample: its component, or a group
    of its own for a labelled sample of a disagreeing component (which spreads to nothing)."""
    n_comp, comp = must_link_components(pairs, num_samples)
    lab_comp = comp[labelled]
    lo = np.full(n_comp, np.iinfo(np.int64).max)
    hi = np.full(n_comp, -1)
    np.minimum.at(lo, lab_comp, labels)
    np.maximum.at(hi, lab_comp, labels)
    agreed = hi >= 0  # components with a labelled member ...
    conflict = agreed & (lo != hi)
    agreed &= ~conflict  # ... whose labelled members all agree
    spread = np.flatnonzero(agreed[comp])  # every member of such a component
    keep = conflict[lab_comp]  # labelled samples of disagreeing components keep their own
    out_idx = np.concatenate([spread, labelled[keep]])
    out_lab = np.concatenate([hi[comp[spread]], labels[keep]])
    group = np.concatenate([comp[spread], n_comp + np.arange(int(keep.sum()))])
    order = np.argsort(out_idx, kind="stable")
    return out_idx[order], out_lab[order], int(conflict.sum()), group[order]


def closure_labels(
    labelled: np.ndarray, labels: np.ndarray, pairs: np.ndarray, num_samples: int
) -> tuple[np.ndarray, np.ndarray, int]:
    """(labelled', labels', conflicting components): the labels spread over the must-link graph.

    labelled (L,) indices, labels (L,) classes, pairs (P, 2) into 0..num_samples-1. Each connected
    component holding labelled samples of one class gives that class to all its members; a
    component whose labelled samples disagree keeps only those samples' own labels.
    """
    labelled = np.asarray(labelled, np.int64)
    labels = np.asarray(labels, np.int64)
    if len(pairs) == 0 or len(labelled) == 0:
        return labelled, labels, 0
    return _closure(labelled, labels, pairs, num_samples)[:3]


class _AnnotationDraw:
    """Labels via constraints drawn per annotation (`closure_draw="annotation"`): each draw picks
    one of the operator's annotations (class-uniformly with `balanced`), then a member of its
    component uniformly. Every annotation keeps the weight it has without constraints; drawing the
    closure's samples uniformly instead weights an annotation by its component's size, and since
    a long track is also the likelier to hold a drawn label, a class's few longest tracks take
    most of its draws (constraint30's bush: one component, 61 %)."""

    def __init__(self, annotation_pos: np.ndarray, annotation_labels: np.ndarray, group: np.ndarray,
                 balanced: bool, rng: np.random.Generator) -> None:
        # annotation_pos: (A,) positions of the annotations among the closure's samples;
        # group: (L',) group (component) id of each of the closure's samples
        self.rng = rng
        self.cycle: _Cycler | _BalancedCycler = (
            _BalancedCycler(annotation_labels, rng) if balanced else _Cycler(len(annotation_pos), rng))
        self.order = np.argsort(group, kind="stable")
        sorted_group = group[self.order]
        g = group[annotation_pos]
        self.start = np.searchsorted(sorted_group, g)  # (A,) first position of each annotation's group
        self.size = np.searchsorted(sorted_group, g, side="right") - self.start  # (A,) its group's size

    def take(self, k: int) -> np.ndarray:
        a = self.cycle.take(k)  # (k,) annotations
        return self.order[self.start[a] + self.rng.integers(0, self.size[a])]  # (k,) closure positions


class _ComponentDraw:
    """Pairs drawn per component (`pair_draw="component"`): each draw picks a component of the
    must-link graph uniformly, then one of the pairs inside it uniformly."""

    def __init__(self, pairs: np.ndarray, num_samples: int, rng: np.random.Generator) -> None:
        self.rng = rng
        _, comp = must_link_components(pairs, num_samples)
        pair_comp = comp[pairs[:, 0]]  # (P,)
        self.order = np.argsort(pair_comp, kind="stable")  # pairs grouped by component
        _, self.start, self.size = np.unique(pair_comp[self.order], return_index=True, return_counts=True)
        self.cycle = _Cycler(len(self.start), rng)

    def take(self, k: int) -> np.ndarray:
        c = self.cycle.take(k)  # (k,) components
        return self.order[self.start[c] + self.rng.integers(0, self.size[c])]  # (k,) pair indices


class _TrackPartners:
    """Must-link is an equivalence: every sample of a track (a connected component of the pair
    graph) has the same class. `draw(left)` gives each left sample a random other member of its
    component, so a pair can join a near and a far view of one object instead of two nearly equal
    consecutive frames."""

    def __init__(self, pairs: np.ndarray, num_samples: int, rng: np.random.Generator) -> None:
        self.rng = rng
        _, comp = must_link_components(pairs, num_samples)
        self.order = np.argsort(comp, kind="stable")  # (M,) samples grouped by component
        sorted_comp = comp[self.order]
        self.start = np.searchsorted(sorted_comp, comp)  # (M,) first position of each sample's component
        self.size = np.searchsorted(sorted_comp, comp, side="right") - self.start  # (M,) component sizes
        self.pos = np.empty(num_samples, np.int64)
        self.pos[self.order] = np.arange(num_samples)  # (M,) position of each sample in `order`

    def draw(self, left: np.ndarray) -> np.ndarray:
        """(n,) a member of each left sample's component other than itself (components have >= 2)."""
        size = self.size[left]
        off = self.rng.integers(0, np.maximum(size - 1, 1))  # (n,) in 0..size-2
        own = self.pos[left] - self.start[left]
        off = off + (off >= own)  # skip the left sample itself
        return self.order[self.start[left] + np.minimum(off, size - 1)]


def learning_rate(config: TrainingConfig, step: int, total_steps: int) -> float:
    """The learning rate at `step` of `total_steps`: constant, or cosine from config.lr to 0."""
    if config.lr_schedule == "cosine":
        return config.lr * 0.5 * (1.0 + math.cos(math.pi * min(step, total_steps) / max(total_steps, 1)))
    return config.lr


PLOT_FILES = ("learning_curve.png", "confusion.png")


def write_training_plots(
    out: Path,
    history: list[EpochRecord],
    selected: int,
    report: ClassificationReport | None,
    loss_threshold: float | None = None,
) -> list[Path]:
    """`learning_curve.png` (loss and validation F per epoch) and, with a validation report,
    `confusion.png` (its row-normalised confusion matrix) under `out`."""
    from pipeline.plots import plot_confusion, plot_learning_curve

    written = []
    if history:
        vf = np.array([r.val_f for r in history])
        written.append(plot_learning_curve(
            np.array([r.loss for r in history]), vf if np.isfinite(vf).any() else None, out / PLOT_FILES[0],
            selected_epoch=selected if selected >= 0 else None,
            loss_threshold=loss_threshold if loss_threshold is not None and math.isfinite(loss_threshold) else None,
        ))
    if report is not None:
        d = report.to_dict()
        written.append(plot_confusion(np.asarray(d["confusion"]), list(d["per_class"]), out / PLOT_FILES[1],
                                      title=f"Validation confusion (mean F {d['mean_f']:.1f})"))
    return written


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
) -> TrainResult:
    """Train the CNN on labels + constraints; return the model chosen by the paper's rule.

    init_model: start from these weights (fine-tuning); else a fresh network from the configs.
    checkpoint_dir: when given, the selected model is written there as `best.pt` and the last
        epoch as `last.pt` (each a self-describing checkpoint, see `pipeline.model`).
    progress: a step bar (`pipeline.progress`); report: a callback receiving `TrainProgress`
        every few steps and after each epoch (the jobs write it into their row).
    stop: polled every step; returning True ends training early (`cancelled=True`), keeping the
        best epoch so far.
    config.threads > 0 sets torch's CPU threads for the run (restored afterwards).
    """
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
                      annotations)
    finally:
        torch.set_num_threads(threads_before)


class _BatchDraw:
    """What each step trains on: m labelled samples and n = pairs_per_label * m pairs."""

    def __init__(self, data: TrainingData, config: TrainingConfig,
                 annotations: tuple[np.ndarray, np.ndarray, np.ndarray] | None, rng: np.random.Generator) -> None:
        num_l, num_p = len(data.labelled), len(data.pairs)
        self.data = data
        self.m = min(config.batch_labelled, num_l)
        self.n = min(config.pairs_per_label * config.batch_labelled, num_p)
        if self.m == 0 and self.n == 0:  # constraints only with pairs_per_label = 0: m pairs per step instead
            self.n = min(config.batch_labelled, num_p)
        m, n = self.m, self.n
        steps = config.steps_per_epoch or max(math.ceil(num_l / m) if m else 0, math.ceil(num_p / n) if n else 0)
        self.steps = max(steps, 1)
        self.labels: _Cycler | _BalancedCycler | _AnnotationDraw | None = None
        if m and annotations is not None:
            self.labels = _AnnotationDraw(annotations[0], annotations[1], annotations[2], config.balanced_labels, rng)
        elif m:
            self.labels = _BalancedCycler(data.labels, rng) if config.balanced_labels else _Cycler(num_l, rng)
        self.pairs: _Cycler | _ComponentDraw | None = None
        if n:
            self.pairs = _ComponentDraw(data.pairs, len(data.samples), rng) if config.pair_draw == "component" \
                else _Cycler(num_p, rng)
        self.partners = _TrackPartners(data.pairs, len(data.samples), rng) if n and config.transitive_pairs else None

    def draw(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(li (m,) into labelled, pi (n,) into pairs, idx (m + 2n,) into samples: labelled, left, right)."""
        li = self.labels.take(self.m) if self.labels else np.zeros(0, np.int64)
        pi = self.pairs.take(self.n) if self.pairs else np.zeros(0, np.int64)
        left = self.data.pairs[pi, 0]
        right = self.partners.draw(left) if self.partners is not None else self.data.pairs[pi, 1]
        return li, pi, np.concatenate([self.data.labelled[li], left, right])


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
    annotations: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
) -> TrainResult:
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
            val_report = evaluate(model, val, config.eval_batch) if val is not None and len(val) else None
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
    return _finish(model, net, chosen, cancelled, metrics, config, model_config, sample_config, checkpoint_dir, stats)


def _finish(model: SampleCNN, net: NetConfig, chosen: _Selection, cancelled: bool, metrics: dict[str, Any],
            config: TrainingConfig, model_config: ModelConfig, sample_config: SampleConfig,
            checkpoint_dir: str | Path | None, stats: dict[str, Any]) -> TrainResult:
    """Load the selected epoch's weights, gather the metrics, write best.pt / last.pt and plots."""
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
        ckpt = save_checkpoint(out / "best.pt", model, model_config, sample_config, metrics, config, input_stats=stats)
        last = model
        if last_state is not None:
            last = build_model(net)
            last.load_state_dict(last_state)
        save_checkpoint(out / "last.pt", last, model_config, sample_config, {"epoch": len(history) - 1}, config,
                        input_stats=stats)
        write_training_plots(out, history, selected, chosen.report, config.loss_threshold)
    return TrainResult(model, history, selected, how, chosen.report, ckpt, cancelled, metrics, stats)
