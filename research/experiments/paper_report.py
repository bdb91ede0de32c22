"""The paper experiment's report: paper.md (tables, notes) and its plots, from the results document
that `research.experiments.paper.run_paper` writes."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from pipeline.classes import SAMPLE_CLASSES

METHOD = {"baseline_min": "sup.", "baseline_max": "sup.", "oracle_objects20": "sup. (oracle)",
          "oracle_object_constraints": "semi-sup. (oracle)"}
TEST_SEED_OFFSET = 1000


def targets(results: dict[str, Any]) -> dict[str, Any]:
    """The issue's targets: constraint100 >= baseline_min + 10 on D; the train/val ordering."""
    out: dict[str, Any] = {}
    if "constraint100" in results and "baseline_min" in results:
        gain = results["constraint100"]["test"]["mean_f"] - results["baseline_min"]["test"]["mean_f"]
        out["test_gain_constraint100_over_baseline_min"] = {"value": round(gain, 2), "target": 10.0, "met": gain >= 10.0}
    order = [n for n in ("baseline_min", "constraint30", "constraint60", "constraint100", "baseline_max") if n in results]
    if len(order) == 5:
        for key in ("train_val", "val"):
            vals = [results[n][key]["mean_f"] for n in order]
            met = all(a < b for a, b in zip(vals[:-1], vals[1:], strict=True))
            out[f"ordering_{key}"] = {"value": [round(v, 2) for v in vals], "met": met}
    return out


def _fmt(v: float | None) -> str:
    return "-" if v is None else f"{v:.1f}"


def markdown(doc: dict[str, Any]) -> str:
    res, cfg = doc["results"], doc["config"]
    head = "| Learning method | Classifier | " + " | ".join(c.capitalize() for c in SAMPLE_CLASSES) + " | Average |"
    rule = "|---|---|" + "---|" * (len(SAMPLE_CLASSES) + 1)

    def table(key: str) -> list[str]:
        rows = [head, rule]
        for name, r in res.items():
            f = r[key]
            rows.append(f"| {METHOD.get(name, 'semi-sup.')} | {name} | "
                        + " | ".join(_fmt(f["f"][c]) for c in SAMPLE_CLASSES) + f" | {_fmt(f['mean_f'])} |")
        return rows

    data_rows = ["| Setting | | " + " | ".join(c.capitalize() for c in SAMPLE_CLASSES) + " |",
                 "|---|---|" + "---|" * len(SAMPLE_CLASSES)]
    for name, d in doc["data"].items():
        data_rows.append(f"| {name} | constraint | " + " | ".join(str(v) for v in d["constraints"]) + " |")
        data_rows.append("| | annotation | " + " | ".join(str(v) for v in d["labels"]) + " |")
        if d.get("closure_labels") is not None and d["closure_labels"] != d["labels"]:
            data_rows.append("| | labels via constraints | " + " | ".join(str(v) for v in d["closure_labels"]) + " |")
    tr, te = doc["scenes"]["train"], doc["scenes"]["test"]
    tgt = doc["targets"]
    lines = [
        f"Simulated training route: seed {cfg['seed']}, campus style {cfg.get('train_style', 'a')}, "
        f"{cfg['frames']} frames, {tr['samples']} samples, "
        f"{tr['labels']} operator labels, {tr['verified_pairs']} verified / {tr['auto_pairs']} automatic constraints "
        f"(automatic link precision {_fmt(100 * tr['auto_pair_precision'] if tr['auto_pair_precision'] else None)} %). "
        f"Test scene D: seed {cfg['seed'] + TEST_SEED_OFFSET}, campus style {cfg.get('test_style', 'a')}, "
        f"{cfg['test_frames']} frames, {te['labels']} labelled samples. "
        f"S={cfg['size']}, {cfg['steps']} steps per setting; a constraint setting's step holds "
        f"{_constraint_step(cfg)}, gamma={cfg['training']['gamma']}, "
        f"70/30 train/validation split by ground-truth object.{_batch_note(res)}",
        "",
        "**Training data per setting** (like the paper's Table 6; constraints by the class of their track; "
        "labels via constraints: the annotations spread over their must-link components, `closure_labels`, "
        f"drawn {_closure_draw(cfg['training'])}):",
        "",
        *data_rows,
        "",
        "**F-measure on the training data** (train + validation samples, like the paper's Table 7):",
        "",
        *table("train_val"),
        "",
        "**F-measure on the validation split only** (30 % of the tracks, never trained on):",
        "",
        *table("val"),
        "",
        "**F-measure on test scene D** (like the paper's Table 8):",
        "",
        *table("test"),
        "",
        *_test_note(doc),
        *_operator_note(doc),
        *_adapt_table(doc),
        "Targets: " + "; ".join(
            f"{k}: {v['value']} ({'met' if v['met'] else 'NOT met'})" for k, v in tgt.items()
        ),
        "",
        f"Time: {doc['seconds']['total']:.0f} s in all (data {doc['seconds']['data']:.0f} s); load average at "
        f"start {_load(doc['machine']['load_average_start'])}, at end {_load(doc['machine']['load_average_end'])}.",
    ]
    return "\n".join(lines) + "\n"


def _operator_note(doc: dict[str, Any]) -> list[str]:
    """A line on the realistic operator's assumed rates and measured errors (none for the careful one)."""
    op = doc.get("operator") or {}
    if not (op.get("miss_rate") or op.get("mislabel_rate")):
        return []
    return [f"Realistic operator on the training route (assumed rates): misses {100 * op['miss_rate']:.0f} % of "
            f"wrong links, mislabels {100 * op['mislabel_rate']:.0f} % of tracks; measured: "
            f"{100 * op['wrong_label_share']:.1f} % of the labels wrong, {100 * op['wrong_pair_share']:.1f} % of "
            "the verified constraints across two objects.", ""]


def _test_note(doc: dict[str, Any]) -> list[str]:
    """The per-class counts D was scored on (docs without them: nothing)."""
    counts = doc["split"].get("test_per_class")
    if not counts:
        return []
    cells = ", ".join(f"{c} {n} ({u} not labelled by the operator)" for c, n, u in
                      zip(SAMPLE_CLASSES, counts["scored"], counts["not_operator_labelled"], strict=True))
    return [f"D is scored on every sample whose majority is a sample class, {sum(counts['scored'])} in all, "
            f"impure ones by their majority class: {cells}.", ""]


def _closure_draw(cfg: dict[str, Any]) -> str:
    """How a doc's labels via constraints were drawn (docs before `closure_draw` drew per sample)."""
    if cfg.get("closure_draw", "sample") == "annotation":
        return "per annotation: an annotation, then a member of its component"
    return "uniformly over the samples"


def _constraint_step(cfg: dict[str, Any]) -> str:
    """'58 labels + 58 pairs (the paper's step: 16 + 80)' from a doc's config (its `constraint_batch`)."""
    m, ppl = cfg["paper_batch_labelled"], cfg["paper_pairs_per_label"]
    cm, c = cfg["constraint_batch"]["batch_labelled"], cfg["constraint_batch"]["pairs_per_label"]
    own = f"{cm} labels + {cm * c} pairs"
    return own if (cm, c) == (m, ppl) else f"{own} (the paper's step: {m} + {m * ppl})"


def _batch_note(res: dict[str, Any]) -> str:
    """' Labels-only settings ...' naming each one's labels per step tried and kept, or ''."""
    picks = [f"{name} {r['training']['batch_labelled']} ("
             + ", ".join(f"{b}: val F {f:.1f}" for b, f in r["batch_select"].items()) + ")"
             for name, r in res.items() if r.get("batch_select")]
    if not picks:
        return ""
    return (" Labels-only settings trained with each labels-per-step value and kept the better on the "
            "validation split: " + "; ".join(picks) + ".")


def _adapt_table(doc: dict[str, Any]) -> list[str]:
    ad = doc.get("adaptation") or {}
    if not ad:
        return []
    rows = ["**Constraints only on D** (the paper's unsupervised adaptation, its Fig. 12: constraint100 trained "
            "further on D's verified constraints, no labels):", "",
            "| Setting | " + " | ".join(c.capitalize() for c in SAMPLE_CLASSES) + " | Average | most predicted class |",
            "|---|" + "---|" * (len(SAMPLE_CLASSES) + 2)]
    before = ad.get("constraint100_before")
    c100 = doc["results"].get("constraint100")
    if before and c100:
        f = c100["test"]
        rows.append("| constraint100 (before) | " + " | ".join(_fmt(f["f"][c]) for c in SAMPLE_CLASSES)
                    + f" | {_fmt(f['mean_f'])} | {before['largest_class']} "
                    f"({100 * max(before['predicted_share']):.0f} %) |")
    for name, r in ad.items():
        if name == "constraint100_before":
            continue
        f = r["test"]
        rows.append(f"| {name} (balance {r['balance_weight']:g}) | " + " | ".join(_fmt(f["f"][c]) for c in SAMPLE_CLASSES)
                    + f" | {_fmt(f['mean_f'])} | {r['largest_class']} ({100 * max(r['predicted_share']):.0f} %) |")
    return [*rows, ""]


def _load(v: list[float] | None) -> str:
    return "-" if not v else ", ".join(f"{x:.2f}" for x in v)


def _plots(doc: dict[str, Any], out: Path) -> None:
    from pipeline.plots import plot_f_bars

    names = list(doc["results"])
    for key, title, fname in (("train_val", "F on training data (train + val)", "paper_train.png"),
                              ("test", "F on test scene D", "paper_test.png")):
        f = np.array([[np.nan if doc["results"][n][key]["f"][c] is None else doc["results"][n][key]["f"][c]
                       for c in SAMPLE_CLASSES] for n in names])
        plot_f_bars(f, names, SAMPLE_CLASSES, out / fname, title=title)
    from pipeline.plots import plot_confusion

    for name in ("baseline_min", "constraint100", "baseline_max"):
        if name in doc["results"]:
            t = doc["results"][name]["test"]
            plot_confusion(np.asarray(t["confusion"]), SAMPLE_CLASSES, out / f"paper_confusion_{name}.png",
                           title=f"{name} on test scene D (mean F {t['mean_f']:.1f})")
