"""Evaluation: per-class precision, recall and F-measure of samples, point-level IoU of frames.

F = 2 P R / (P + R) x 100, as the paper defines it (Eq. 13). A class with P + R = 0 scores 0.
Averages are over the classes that occur in the ground truth (support > 0); a class absent
from both truth and prediction has NaN precision, recall and F and is left out of the average.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from pipeline.classes import NUM_SAMPLE_CLASSES, POINT_CLASSES, SAMPLE_CLASSES, UNLABELLED


def confusion_matrix(
    truth: np.ndarray, pred: np.ndarray, num_classes: int, ignore: int = UNLABELLED
) -> np.ndarray:
    """(K, K) int64 counts, rows = truth, columns = prediction.

    Entries whose truth is `ignore` are dropped. A prediction of `ignore` (or any id >= K)
    where the truth is labelled counts in no column, so it lowers recall but no precision.
    """
    truth = np.asarray(truth).ravel().astype(np.int64)
    pred = np.asarray(pred).ravel().astype(np.int64)
    if truth.shape != pred.shape:
        raise ValueError(f"truth and prediction differ in length: {truth.shape} vs {pred.shape}")
    keep = truth != ignore
    truth, pred = truth[keep], pred[keep]
    if truth.size and (truth.min() < 0 or truth.max() >= num_classes):
        raise ValueError(f"truth holds class ids outside 0..{num_classes - 1}")
    pred = np.where((pred >= 0) & (pred < num_classes), pred, num_classes)  # K = "no class"
    counts = np.bincount(truth * (num_classes + 1) + pred, minlength=num_classes * (num_classes + 1))
    return counts.reshape(num_classes, num_classes + 1)[:, :num_classes]


@dataclass(frozen=True)
class ClassificationReport:
    """Per-class scores of a sample classifier.

    precision, recall: (K,) float64 in [0, 1], NaN where undefined (no support, no predictions).
    f:                 (K,) float64 F-measure x 100, NaN for a class absent from truth and prediction.
    support:           (K,) int64 true samples per class.
    confusion:         (K, K) int64, rows = truth, columns = prediction.
    """

    precision: np.ndarray
    recall: np.ndarray
    f: np.ndarray
    support: np.ndarray
    confusion: np.ndarray
    classes: tuple[str, ...] = SAMPLE_CLASSES

    @property
    def mean_f(self) -> float:
        """Average F (x 100) over the classes with support > 0; NaN when there are none."""
        present = self.support > 0
        return float(np.mean(self.f[present])) if present.any() else float("nan")

    @property
    def accuracy(self) -> float:
        total = self.support.sum()
        return float(np.trace(self.confusion) / total) if total else float("nan")

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready: per-class dicts plus averages and the confusion matrix (NaN -> None)."""

        def num(v: float) -> float | None:
            return None if np.isnan(v) else round(float(v), 6)

        return {
            "classes": list(self.classes),
            "per_class": {
                name: {
                    "precision": num(self.precision[k]),
                    "recall": num(self.recall[k]),
                    "f": num(self.f[k]),
                    "support": int(self.support[k]),
                }
                for k, name in enumerate(self.classes)
            },
            "mean_f": num(self.mean_f),
            "accuracy": num(self.accuracy),
            "confusion": self.confusion.tolist(),
        }


def _ratio(num: np.ndarray, den: np.ndarray) -> np.ndarray:
    out = np.full(num.shape, np.nan)
    np.divide(num, den, out=out, where=den > 0)
    return out


def classification_report(
    truth: np.ndarray,
    pred: np.ndarray,
    num_classes: int = NUM_SAMPLE_CLASSES,
    classes: tuple[str, ...] = SAMPLE_CLASSES,
) -> ClassificationReport:
    """Scores of predicted class ids (N,) against true class ids (N,) (255 = ignored)."""
    cm = confusion_matrix(truth, pred, num_classes)
    tp = np.diag(cm).astype(np.float64)
    support = cm.sum(axis=1)
    predicted = cm.sum(axis=0)
    precision = _ratio(tp, predicted.astype(np.float64))
    recall = _ratio(tp, support.astype(np.float64))
    p0, r0 = np.nan_to_num(precision), np.nan_to_num(recall)
    f = np.where(p0 + r0 > 0, 2 * p0 * r0 / np.where(p0 + r0 > 0, p0 + r0, 1.0), 0.0) * 100.0
    f = np.where((support == 0) & (predicted == 0), np.nan, f)
    return ClassificationReport(precision, recall, f, support, cm, tuple(classes[:num_classes]))


@dataclass(frozen=True)
class IoUReport:
    """Point-level intersection over union per class.

    iou:       (K,) float64 in [0, 1], NaN for a class absent from truth and prediction.
    confusion: (K, K) int64 point counts, rows = truth, columns = prediction.
    """

    iou: np.ndarray
    confusion: np.ndarray
    classes: tuple[str, ...] = POINT_CLASSES

    @property
    def mean_iou(self) -> float:
        """Mean over the classes that occur in the truth."""
        present = self.confusion.sum(axis=1) > 0
        return float(np.mean(self.iou[present])) if present.any() else float("nan")

    def to_dict(self) -> dict[str, Any]:
        return {
            "classes": list(self.classes),
            "iou": {
                n: (None if np.isnan(v) else round(float(v), 6)) for n, v in zip(self.classes, self.iou, strict=True)
            },
            "mean_iou": None if np.isnan(self.mean_iou) else round(self.mean_iou, 6),
            "confusion": self.confusion.tolist(),
        }


def point_iou(
    pred_frames: Sequence[np.ndarray],
    truth_frames: Sequence[np.ndarray],
    num_classes: int = len(POINT_CLASSES),
    classes: tuple[str, ...] = POINT_CLASSES,
) -> IoUReport:
    """IoU per point class of predicted frames against labelled frames.

    Each frame is an (N_f,) array of class indices of one label set (the default set's by default;
    255 = unlabelled). Points whose truth is 255 are ignored; a labelled point predicted 255 is a
    miss of its true class.
    IoU_k = TP / (TP + FP + FN).
    """
    if len(pred_frames) != len(truth_frames):
        raise ValueError(f"{len(pred_frames)} predicted frames vs {len(truth_frames)} labelled frames")
    cm = np.zeros((num_classes, num_classes), dtype=np.int64)
    missed = np.zeros(num_classes, dtype=np.int64)  # labelled points predicted as no class
    for pred, truth in zip(pred_frames, truth_frames, strict=True):
        truth = np.asarray(truth).astype(np.int64)
        full = confusion_matrix(truth, pred, num_classes)
        cm += full
        labelled = truth[truth != UNLABELLED]
        missed += np.bincount(labelled, minlength=num_classes)[:num_classes] - full.sum(axis=1)
    tp = np.diag(cm).astype(np.float64)
    union = cm.sum(axis=1) + missed + cm.sum(axis=0) - tp
    return IoUReport(_ratio(tp, union.astype(np.float64)), cm, tuple(classes[:num_classes]))
