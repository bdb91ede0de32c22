"""The training run's plots: learning curve and confusion matrix."""

from __future__ import annotations

import math
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from pipeline.metrics import ClassificationReport

if TYPE_CHECKING:  # the loop imports this module
    from pipeline.training.loop import EpochRecord

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
