"""The spread of the paper experiment over runs: each target of the honest evaluation as the mean
and range over several (scene seed, label draw, training seed) combinations.

`tracklabel experiment spread RUN_DIR... --out OUT` reads each RUN_DIR/paper.json (written by
`tracklabel experiment paper`) and writes OUT/spread.json, OUT/spread.md and OUT/spread.png (F on
D and on train/val per setting: the mean, and the range as error bars).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

ORDER = ("baseline_min", "constraint30", "constraint60", "constraint100", "baseline_max")
GAIN_TARGET = 10.0  # constraint100 - baseline_min on D, F points
GAP_TARGET = 5.0  # baseline_max - constraint100 on D, F points, at most


def run_label(doc: dict[str, Any]) -> str:
    """'scene 7301, labels 7301, training 7301': what a run drew its scenes, labels and training from."""
    cfg = doc["config"]
    seed = cfg["seed"]
    labels = "split stream" if cfg.get("label_seed") is None else cfg["label_seed"]
    train = seed if cfg.get("train_seed") is None else cfg["train_seed"]
    return f"scene {seed}, labels {labels}, training {train}"


def _stats(values: list[float]) -> dict[str, Any]:
    v = np.asarray(values, np.float64)
    return {"values": [round(float(x), 2) for x in v], "mean": round(float(v.mean()), 2),
            "min": round(float(v.min()), 2), "max": round(float(v.max()), 2)}


def spread(docs: list[dict[str, Any]]) -> dict[str, Any]:
    """Per target: the value of each run, their mean and range, and whether the mean meets it."""
    def f(doc: dict[str, Any], name: str, key: str) -> float:
        return float(doc["results"][name][key]["mean_f"])

    gain = _stats([f(d, "constraint100", "test") - f(d, "baseline_min", "test") for d in docs])
    gap = _stats([f(d, "baseline_max", "test") - f(d, "constraint100", "test") for d in docs])
    means = {key: {n: _stats([f(d, n, key) for d in docs]) for n in ORDER} for key in ("train_val", "val", "test")}
    order_means = [means["train_val"][n]["mean"] for n in ORDER]
    per_run_order = [all(f(d, a, "train_val") < f(d, b, "train_val") for a, b in zip(ORDER[:-1], ORDER[1:], strict=True))
                     for d in docs]
    return {
        "runs": [run_label(d) for d in docs],
        "targets": {
            "gain_on_d": gain | {"target": f">= {GAIN_TARGET}", "met": gain["mean"] >= GAIN_TARGET},
            "order_train_val": {"means": order_means, "per_run_met": per_run_order,
                                "met": all(a < b for a, b in zip(order_means[:-1], order_means[1:], strict=True))},
            "gap_to_baseline_max_on_d": gap | {"target": f"<= {GAP_TARGET}", "met": gap["mean"] <= GAP_TARGET},
        },
        "f": means,
    }


def markdown(result: dict[str, Any]) -> str:
    """The per-setting table (mean [min, max]) and the targets."""
    def cell(s: dict[str, Any]) -> str:
        return f"{s['mean']:.1f} [{s['min']:.1f}, {s['max']:.1f}]"

    rows = ["| setting | train/val | val | D |", "|---|---|---|---|"]
    for n in ORDER:
        rows.append(f"| {n} | " + " | ".join(cell(result["f"][k][n]) for k in ("train_val", "val", "test")) + " |")
    t = result["targets"]
    lines = [f"Runs: {'; '.join(result['runs'])}.", "", "Average F, mean [min, max] over the runs:", "", *rows, "",
             f"- constraint100 - baseline_min on D: {cell(t['gain_on_d'])} (target {t['gain_on_d']['target']}: "
             f"{'met' if t['gain_on_d']['met'] else 'NOT met'}); per run {t['gain_on_d']['values']}",
             f"- order on train/val, means {t['order_train_val']['means']}: "
             f"{'met' if t['order_train_val']['met'] else 'NOT met'}; per run {t['order_train_val']['per_run_met']}",
             f"- baseline_max - constraint100 on D: {cell(t['gap_to_baseline_max_on_d'])} (target "
             f"{t['gap_to_baseline_max_on_d']['target']}: {'met' if t['gap_to_baseline_max_on_d']['met'] else 'NOT met'}); "
             f"per run {t['gap_to_baseline_max_on_d']['values']}"]
    return "\n".join(lines) + "\n"


def plot(result: dict[str, Any], path: Path) -> None:
    """Bars of the mean F per setting on train/val and on D, the range over runs as error bars."""
    from pipeline.plots import _pyplot, _save

    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(7.0, 3.8))
    x = np.arange(len(ORDER))
    for i, (key, name) in enumerate((("train_val", "train/val"), ("test", "test scene D"))):
        s = [result["f"][key][n] for n in ORDER]
        mean = np.array([v["mean"] for v in s])
        err = np.array([[v["mean"] - v["min"] for v in s], [v["max"] - v["mean"] for v in s]])
        ax.bar(x + (i - 0.5) * 0.38, mean, 0.38, yerr=err, capsize=3, label=name)
    ax.set_xticks(x, ORDER, rotation=15)
    ax.set_ylim(50, 100)
    ax.set_ylabel("average F")
    ax.set_title(f"Mean and range over {len(result['runs'])} runs")
    ax.legend(fontsize=8)
    ax.grid(axis="y", alpha=0.3)
    _save(fig, path)


def write_spread(out: str | Path, run_dirs: list[str | Path]) -> dict[str, Any]:
    """Read RUN_DIR/paper.json of each run; write OUT/spread.json, spread.md and spread.png."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    result = spread([json.loads((Path(d) / "paper.json").read_text()) for d in run_dirs])
    (out / "spread.json").write_text(json.dumps(result, indent=1))
    (out / "spread.md").write_text(markdown(result))
    plot(result, out / "spread.png")
    return result
