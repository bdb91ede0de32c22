"""`tracklabel experiment levers`: why constraint100 trails baseline_max, and what moves it,
measured on the validation split of the paper experiment's route (never on its test scene D).

1. The paper experiment's data (`research.experiments.paper`): the route, its split by object.
2. baseline_min, baseline_max and constraint100 trained with the product's training, then each
   lever (`LEVERS`: a change of constraint100's training or of its pair weights) in its place;
   all scored on the validation objects (per class, with the confusion).
3. The pull: the constraint term alone shapes the training-side components of the must-link
   graph that hold none of the few labels (the label closure covers the others). Over the pairs
   drawn from those components, the share of each (true class, predicted class) for
   baseline_min (where the constraints start from) and for constraint100 (where they pull to),
   and the simulator's kinds of objects behind the largest wrong pulls.

Writes `levers.md`, `levers.json` and `levers.png` (validation F per class of each setting).
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, field_validator

from pipeline.classes import NUM_SAMPLE_CLASSES, SAMPLE_CLASSES
from pipeline.config import ModelConfig
from pipeline.progress import QUIET, Progress
from research.experiments.paper import PaperConfig, _prepare, _Run, _train_setting, setting_data

# each lever: (training-config changes, model-config changes, pair weights); constraint100 with it
LEVERS: dict[str, tuple[dict[str, Any], dict[str, Any], str]] = {
    "constraint100": ({}, {}, "ones"),
    "gamma_0.5": ({"gamma": 0.5}, {}, "ones"),
    "squared_difference": ({"constraint_loss": "squared"}, {}, "ones"),
    "component_draws": ({"pair_draw": "component"}, {}, "ones"),
    "score_weighted": ({}, {}, "score"),
    "wider_network": ({}, {"width": 48, "max_width": 192}, "ones"),
}
REFERENCES = ("baseline_min", "baseline_max")


class LeversConfig(BaseModel):
    """The paper experiment's config (scene seed, label draw, training) and the levers to try."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    paper: PaperConfig = PaperConfig(settings=("baseline_min", "constraint100", "baseline_max"), adapt=())
    levers: tuple[str, ...] = tuple(LEVERS)
    top_kinds: int = Field(default=6, ge=1)

    @field_validator("levers")
    @classmethod
    def _known(cls, v: tuple[str, ...]) -> tuple[str, ...]:
        bad = [name for name in v if name not in LEVERS]
        if bad:
            raise ValueError(f"unknown {', '.join(bad)}; valid: {', '.join(LEVERS)}")
        return v


def verified_pair_scores(scene: Any, pairs: np.ndarray) -> np.ndarray:
    """(P,) the association's score of each verified pair: a track link's score (the later
    sample's `link_score`), a confirmed stitch's shared-point share; 1 where neither is known."""
    frag = {(int(a), int(b)): float(s) for (a, b), s in zip(scene.fragment_pairs, scene.fragment_scores, strict=True)}
    link = scene.link_score[pairs[:, 1]].astype(np.float64)  # (P,) NaN at a track's start
    out = np.where(np.isfinite(link), link, 1.0)
    for i, (a, b) in enumerate(pairs):
        if (int(a), int(b)) in frag:
            out[i] = frag[(int(a), int(b))]
    return np.clip(out, 0.0, 1.0).astype(np.float32)


def _val_row(model: Any, run: _Run, seconds: float) -> dict[str, Any]:
    from pipeline.training import LabelledSamples, evaluate

    idx = run.evals["val"]
    d = evaluate(model, LabelledSamples(run.scene.samples[idx], run.route_truth[idx])).to_dict()
    return {"val_f": round(d["mean_f"], 2), "f": {c: _round(d["per_class"][c]["f"]) for c in SAMPLE_CLASSES},
            "confusion": d["confusion"], "seconds": round(seconds, 1)}


def _round(v: float | None) -> float | None:
    return None if v is None else round(v, 1)


def _train_lever(name: str, run: _Run) -> tuple[Any, float]:
    """(constraint100's model trained with lever `name`, seconds)."""
    from pipeline.training import TrainingData, train

    tcfg, mcfg, weights = LEVERS[name]
    labelled, pairs, _ = setting_data("constraint100", run.scene, run.split, run.cfg.unknown_constraints)
    w = verified_pair_scores(run.scene, pairs) if weights == "score" else np.ones(len(pairs), np.float32)
    data = TrainingData.build(run.scene.samples, labelled, run.scene.label[labelled].astype(np.int64), pairs, w)
    cfg = run.cfg.setting_config("constraint100").model_copy(update=tcfg)
    t0 = time.perf_counter()
    res = train(data, cfg, ModelConfig(**mcfg), run.sample_cfg, val=run.val_select, progress=run.progress)
    return res.model, time.perf_counter() - t0


def _train_reference(name: str, run: _Run) -> tuple[Any, float]:
    """(baseline_min's or baseline_max's model as the paper experiment trains it, seconds)."""
    from pipeline.training import TrainingData

    labelled, pairs, weights = setting_data(name, run.scene, run.split)
    data = TrainingData.build(run.scene.samples, labelled, run.scene.label[labelled].astype(np.int64), pairs, weights)
    t0 = time.perf_counter()
    res, _ = _train_setting(name, run, data, True)
    return res.model, time.perf_counter() - t0


def object_kinds(run: _Run) -> dict[int, str]:
    """Instance id -> the simulator's kind of object (tree_crown, hedge_flush, ...), from the
    route's campus rebuilt without casting (`research.simulation.build_scene`)."""
    from research.simulation.scene import build_scene

    cfg = run.cfg
    scene = build_scene(cfg.seed, crowd=cfg.crowd, cyclists=cfg.cyclists, style=cfg.train_style)
    return {int(iid): info.kind for iid, info in scene.instances.items()}


def pull(run: _Run, models: dict[str, Any], kinds: dict[int, str], top: int) -> dict[str, Any]:
    """What the constraint term alone shapes (module docstring, step 3): over the pairs drawn from
    constraint100's training-side components that hold no label, the share of each (true class,
    predicted class) per model, and per wrong (true, predicted) cell of constraint100 the kinds of
    objects behind it."""
    from pipeline.model import predict
    from pipeline.training import must_link_components

    scene, split = run.scene, run.split
    _, pairs, _ = setting_data("constraint100", scene, split, run.cfg.unknown_constraints)
    _, comp = must_link_components(pairs, len(scene))
    labelled_comp = np.unique(comp[split.min_labelled])
    drawn = pairs[~np.isin(comp[pairs[:, 0]], labelled_comp), 0]  # left samples of unlabelled components' pairs
    truth = run.route_truth[drawn]
    drawn, truth = drawn[truth >= 0], truth[truth >= 0]
    uniq, inverse = np.unique(drawn, return_inverse=True)
    k = NUM_SAMPLE_CLASSES
    out: dict[str, Any] = {"pairs": int(len(pairs)), "unlabelled_component_pairs": int(len(drawn)),
                           "unlabelled_component_share": round(len(drawn) / max(len(pairs), 1), 4), "tables": {}}
    preds = {}
    for name, model in models.items():
        preds[name] = predict(model, scene.samples[uniq]).argmax(1)[inverse]
        table = np.zeros((k, k), np.int64)
        np.add.at(table, (truth, preds[name]), 1)
        out["tables"][name] = table.tolist()
    out["kinds"] = _wrong_pull_kinds(scene, drawn, truth, preds, kinds, top)
    return out


def _wrong_pull_kinds(scene: Any, drawn: np.ndarray, truth: np.ndarray, preds: dict[str, np.ndarray],
                      kinds: dict[int, str], top: int) -> list[dict[str, Any]]:
    """The largest wrong cells of constraint100's pull table, each with its top kinds of objects
    (share of the cell's pair draws) and what baseline_min predicted for those draws."""
    c100, bmin = preds["constraint100"], preds["baseline_min"]
    wrong = truth != c100
    cells, counts = np.unique(np.stack([truth[wrong], c100[wrong]], 1), axis=0, return_counts=True)
    rows = []
    kind = np.array([kinds.get(int(o) & 0xFFFFFFFF, "?") for o in scene.gt_object[drawn]])
    for (t, p), n in sorted(zip(cells.tolist(), counts.tolist(), strict=True), key=lambda r: -r[1])[:8]:
        sel = (truth == t) & (c100 == p)
        names, per = np.unique(kind[sel], return_counts=True)
        order = np.argsort(-per)[:top]
        rows.append({"true": SAMPLE_CLASSES[t], "predicted": SAMPLE_CLASSES[p], "pairs": int(n),
                     "share_of_true_class": round(n / max(int((truth == t).sum()), 1), 4),
                     "baseline_min_already": round(float(np.mean(bmin[sel] == p)), 4),
                     "kinds": {str(names[i]): round(per[i] / n, 3) for i in order}})
    return rows


def run_levers(out: str | Path, cfg: LeversConfig | None = None, cache: str | Path | None = None,
               progress: Progress = QUIET, log: Any = None) -> dict[str, Any]:
    """Run the study (module docstring); writes OUT/levers.md, levers.json, levers.png."""
    cfg = cfg or LeversConfig()
    log = log or (lambda _m: None)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    t_start = time.perf_counter()
    run = _prepare(cfg.paper, Path(cache) if cache is not None else out / "cache", progress, log)
    rows: dict[str, Any] = {}
    models: dict[str, Any] = {}
    names = [*REFERENCES, *cfg.levers]
    with progress.bar(len(names), "levers", unit="setting", position=0) as bar:
        for name in names:
            model, seconds = (_train_reference if name in REFERENCES else _train_lever)(name, run)
            rows[name] = _val_row(model, run, seconds)
            if name in ("baseline_min", "constraint100"):
                models[name] = model
            log(f"{name}: validation F {rows[name]['val_f']:.1f} ({seconds:.0f} s)")
            bar.update()
    doc: dict[str, Any] = {"config": cfg.model_dump(mode="json"), "validation": rows,
                           "validation_samples": int(len(run.evals["val"]))}
    if "constraint100" in models:
        doc["pull"] = pull(run, models, object_kinds(run), cfg.top_kinds)
    doc["seconds"] = round(time.perf_counter() - t_start, 1)
    (out / "levers.json").write_text(json.dumps(doc, indent=1))
    (out / "levers.md").write_text(markdown(doc))
    _plot(doc, out / "levers.png")
    return doc


def markdown(doc: dict[str, Any]) -> str:
    paper = doc["config"]["paper"]
    lines = [f"# Levers on constraint100 (scene seed {paper['seed']}, validation split, "
             f"{doc['validation_samples']} samples)", "",
             "| setting | " + " | ".join(SAMPLE_CLASSES) + " | mean F | seconds |",
             "|---" * (len(SAMPLE_CLASSES) + 3) + "|"]
    for name, row in doc["validation"].items():
        lines.append(f"| {name} | " + " | ".join("-" if row["f"][c] is None else f"{row['f'][c]:.1f}" for c in SAMPLE_CLASSES)
                     + f" | **{row['val_f']:.1f}** | {row['seconds']:.0f} |")
    if "pull" in doc:
        lines += ["", *_pull_markdown(doc["pull"])]
    return "\n".join(lines) + "\n"


def _pull_markdown(p: dict[str, Any]) -> list[str]:
    lines = [f"## The pull: {p['unlabelled_component_pairs']} of {p['pairs']} constraint100 pairs "
             f"({100 * p['unlabelled_component_share']:.0f} %) lie in components without a label",
             "", "Share of those pairs predicted as each class, per true class (rows), baseline_min -> constraint100:", "",
             "| true \\ predicted | " + " | ".join(SAMPLE_CLASSES) + " |", "|---" * (len(SAMPLE_CLASSES) + 1) + "|"]
    bmin, c100 = np.asarray(p["tables"]["baseline_min"], float), np.asarray(p["tables"]["constraint100"], float)
    for t, name in enumerate(SAMPLE_CLASSES):
        a, b = bmin[t] / max(bmin[t].sum(), 1), c100[t] / max(c100[t].sum(), 1)
        lines.append(f"| {name} ({int(bmin[t].sum())}) | "
                     + " | ".join(f"{100 * x:.0f} → {100 * y:.0f}" for x, y in zip(a, b, strict=True)) + " |")
    lines += ["", "Largest wrong pulls of constraint100 and the kinds of objects behind them:", "",
              "| true → predicted | pairs | share of the true class | baseline_min already | kinds |", "|---|---|---|---|---|"]
    for r in p["kinds"]:
        kinds = ", ".join(f"{k} {100 * v:.0f} %" for k, v in r["kinds"].items())
        lines.append(f"| {r['true']} → {r['predicted']} | {r['pairs']} | {100 * r['share_of_true_class']:.0f} % "
                     f"| {100 * r['baseline_min_already']:.0f} % | {kinds} |")
    return lines


def _plot(doc: dict[str, Any], path: Path) -> None:
    from pipeline.plots import plot_f_bars

    rows = doc["validation"]
    f = np.array([[np.nan if rows[n]["f"][c] is None else rows[n]["f"][c] for c in SAMPLE_CLASSES] for n in rows])
    plot_f_bars(f, list(rows), SAMPLE_CLASSES, path, title="constraint100's levers: F on the validation objects")
