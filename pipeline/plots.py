"""PNG figures from plain arrays: confusion matrix, learning curve, grouped per-class F bars.

matplotlib (Agg backend) is imported inside each function, so importing this module is cheap.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np


def _pyplot():  # noqa: ANN202 - matplotlib.pyplot module
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _save(fig, path: str | Path) -> Path:  # noqa: ANN001 - matplotlib Figure
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120, bbox_inches="tight")
    _pyplot().close(fig)
    return path


def plot_confusion(
    confusion: np.ndarray,
    classes: Sequence[str],
    path: str | Path,
    title: str = "Confusion matrix",
    normalise: bool = True,
) -> Path:
    """Confusion matrix (K, K) (rows = truth) as a heat map; cells show row share or counts."""
    plt = _pyplot()
    cm = np.asarray(confusion, dtype=np.float64)
    k = len(classes)
    assert cm.shape == (k, k), (cm.shape, k)
    rows = cm.sum(axis=1, keepdims=True)
    shown = np.divide(cm, rows, out=np.zeros_like(cm), where=rows > 0) if normalise else cm
    fig, ax = plt.subplots(figsize=(1.0 + 0.8 * k, 0.8 + 0.7 * k))
    im = ax.imshow(shown, cmap="Blues", vmin=0.0, vmax=1.0 if normalise else None)
    ax.set_xticks(range(k), labels=list(classes), rotation=45, ha="right")
    ax.set_yticks(range(k), labels=list(classes))
    ax.set_xlabel("predicted")
    ax.set_ylabel("true")
    ax.set_title(title)
    top = shown.max() if shown.size else 1.0
    for i in range(k):
        for j in range(k):
            text = f"{shown[i, j]:.2f}" if normalise else f"{int(cm[i, j])}"
            ax.text(j, i, text, ha="center", va="center", fontsize=7,
                    color="white" if shown[i, j] > 0.6 * top else "black")  # fmt: skip
    fig.colorbar(im, ax=ax, fraction=0.046)
    return _save(fig, path)


def plot_learning_curve(
    train_loss: np.ndarray,
    val_f: np.ndarray | None,
    path: str | Path,
    selected_epoch: int | None = None,
    loss_threshold: float | None = None,
    title: str = "Learning curve",
) -> Path:
    """Training loss per epoch (left axis) and validation mean F (right axis), epochs from 1."""
    plt = _pyplot()
    loss = np.asarray(train_loss, dtype=np.float64)
    epochs = np.arange(1, len(loss) + 1)
    fig, ax = plt.subplots(figsize=(6.4, 4.0))
    ax.plot(epochs, loss, "o-", color="tab:blue", label="train loss", markersize=3)
    if loss_threshold is not None:
        ax.axhline(loss_threshold, color="tab:blue", linestyle=":", linewidth=1, label="loss threshold")
    ax.set_xlabel("epoch")
    ax.xaxis.get_major_locator().set_params(integer=True)
    ax.set_ylabel("train loss", color="tab:blue")
    handles, labels = ax.get_legend_handles_labels()
    if val_f is not None and len(val_f):
        ax2 = ax.twinx()
        ax2.plot(epochs, np.asarray(val_f, dtype=np.float64), "s-", color="tab:orange", label="val mean F",
                 markersize=3)  # fmt: skip
        ax2.set_ylabel("validation mean F", color="tab:orange")
        ax2.set_ylim(0, 100)
        h2, l2 = ax2.get_legend_handles_labels()
        handles, labels = handles + h2, labels + l2
    if selected_epoch is not None:
        ax.axvline(selected_epoch + 1, color="grey", linestyle="--", linewidth=1)
        handles.append(ax.lines[-1])
        labels.append(f"selected (epoch {selected_epoch + 1})")
    ax.legend(handles, labels, loc="center right", fontsize=8)
    ax.set_title(title)
    return _save(fig, path)


def plot_f_bars(
    f_values: np.ndarray,
    settings: Sequence[str],
    classes: Sequence[str],
    path: str | Path,
    title: str = "F-measure per class",
) -> Path:
    """Grouped bars: one group per class (plus the average), one bar per setting.

    f_values: (n_settings, n_classes) F x 100, NaN = not measured (drawn as no bar).
    """
    plt = _pyplot()
    f = np.asarray(f_values, dtype=np.float64)
    assert f.shape == (len(settings), len(classes)), (f.shape, len(settings), len(classes))
    with np.errstate(all="ignore"):
        mean = np.array([np.nanmean(row) if np.isfinite(row).any() else np.nan for row in f])
    data = np.column_stack([f, mean])  # (n_settings, n_classes + 1)
    groups = [*classes, "average"]
    x = np.arange(len(groups))
    width = 0.8 / max(len(settings), 1)
    fig, ax = plt.subplots(figsize=(max(6.4, 1.1 * len(groups)), 4.0))
    colours = plt.get_cmap("tab10" if len(settings) <= 10 else "tab20")  # distinct beyond ten settings
    for i, name in enumerate(settings):
        ax.bar(x - 0.4 + width * (i + 0.5), np.nan_to_num(data[i]), width, label=name, color=colours(i % colours.N))
    ax.set_xticks(x, labels=groups, rotation=30, ha="right")
    ax.set_ylabel("F-measure")
    ax.set_ylim(0, 100)
    ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    ax.set_title(title)
    return _save(fig, path)


def quantile_comparison(
    stats: dict[str, dict[str, dict]],
    metrics: dict[str, str],
    path: str | Path,
    log: set[str] | frozenset[str] = frozenset(),
    title: str = "Real vs simulated, per class",
) -> Path:
    """One panel per metric; per class one row per source: a thin line from the 10th to the 90th
    percentile, a thick bar from the 25th to the 75th, a tick at the median.

    stats: {source: {class: {metric: [p10, p25, p50, p75, p90] or None}}}; metrics: {key: axis label};
    log: metrics drawn on a log axis.
    """
    plt = _pyplot()
    sources = list(stats)
    classes = list(dict.fromkeys(c for s in stats.values() for c in s))
    colours = plt.get_cmap("tab10")
    fig, axes = plt.subplots(1, len(metrics), figsize=(4.2 * len(metrics), 0.55 * len(classes) * len(sources) + 1.2),
                             sharey=True)
    axes = np.atleast_1d(axes)
    step = 1.0 / (len(sources) + 1)
    for ax, (key, label) in zip(axes, metrics.items(), strict=True):
        for j, src in enumerate(sources):
            for i, cls in enumerate(classes):
                q = stats[src].get(cls, {}).get(key)
                if not q:
                    continue
                y = i + (j + 1) * step - 0.5
                ax.plot([q[0], q[4]], [y, y], color=colours(j), linewidth=1)
                ax.plot([q[1], q[3]], [y, y], color=colours(j), linewidth=5, solid_capstyle="butt",
                        label=src if i == 0 else None)
                ax.plot([q[2]], [y], "|", color="black", markersize=9)
        if key in log:
            ax.set_xscale("log")
        ax.set_xlabel(label)
        ax.grid(axis="x", alpha=0.3)
    axes[0].set_yticks(range(len(classes)), labels=classes)
    axes[0].invert_yaxis()
    axes[-1].legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    fig.suptitle(title)
    return _save(fig, path)
