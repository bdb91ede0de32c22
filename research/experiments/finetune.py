"""`tracklabel experiment finetune`: the paper's Table 10 protocol on a simulated new scene.

1. Prepare a training route (seed `train_seed`), a development scene (seed `dev_seed`) and a new
   scene D (seed `test_seed`: another layout; both of campus style `test_style`: other cars,
   trees, shrubs and clothes) with `research.experiments.data` (simulation, the real perception
   pipeline, and a ground-truth-checking operator who gives labels and verified constraints).
2. Pretrain on the training route, its labels split 70/30 by ground-truth object (as the paper
   experiment; one validation set for all three), the paper's selection rule:
   - baseline_min: `min_labels` labelled samples per class of the training side (the paper: 350);
   - constraint100: baseline_min's labels + every verified constraint of the training side;
   - baseline_max: every label of the training side.
3. On the development scene, fine-tune constraint100 for each anchor strategy and each budget b
   (proposals per class, `unknown_ratio` x b for unknown: the paper's 20 / 100 at b = 20). A
   simulated operator answers each proposal from ground truth: a sample-level proposal gets its
   sample's true class (or is rejected when the sample is mostly ground / unlabelled); a
   track-level proposal labels the track as the careful operator of `data` would (accepted and
   truncated at its first wrong link; rejected when nothing of it survives). Training adds the
   scene's constraints (`constraints`: verified, the paper, or automatic weighted by association
   score). The strategy with the best F on the development scene's samples the operator did not
   label, at the largest budget <= 20, is the one reported (`choose_strategy`).
4. Fine-tune with that strategy on D at each budget, and evaluate every model on all of D's
   samples whose majority is a sample class: per-class F (the paper's Table 10 rows), and for
   the fine-tuned ones also on D without the samples the operator labelled (held out), beside
   baseline_max's F on the same samples: the target (`finetune_target`).

Writes under `out`: finetune.json (everything), finetune.md (the Table 10 layout), finetune_f.png
(per-class F bars), finetune_curve.png / finetune_curve.json (each strategy's average F on the development scene
and the chosen one's on D against the number of confirmations per class, with D's baseline_max
and constraint100 as lines).
"""

from __future__ import annotations

import hashlib
import json
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, field_validator

from pipeline.anchors import DEFAULT_STRATEGY, STRATEGIES, TRACK_STRATEGIES, class_counts, propose
from pipeline.classes import NUM_SAMPLE_CLASSES, SAMPLE_CLASSES
from pipeline.config import ModelConfig, SampleConfig, TrainingConfig
from pipeline.finetune import finetune, finetune_data
from pipeline.metrics import classification_report
from pipeline.model import SampleCNN, embed, load_checkpoint, predict
from pipeline.progress import QUIET, Progress
from pipeline.training import LabelledSamples, TrainingData, train
from research.experiments.data import (
    SceneSamples,
    code_fingerprint,
    ground_truth_label,
    prepare_scene,
    split_by_object,
    training_side,
)

K = NUM_SAMPLE_CLASSES
UNKNOWN = K - 1


class FinetuneExperimentConfig(BaseModel):
    """Sizes of the experiment (named variants: research/configs/finetune-*.yaml). The defaults run
    in about 45 minutes on 2 CPU cores (most of it the 20 fine-tuning runs). Pretraining and
    fine-tuning train with the product's defaults: `TrainingConfig()` and
    `TrainingConfig().finetuning()` (the REST train and finetune jobs' configs)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    train_seed: int = 0
    test_seed: int = 1000  # the same new scene D as `tracklabel experiment paper`
    train_frames: int = Field(default=1200, ge=20)  # the same route and new scene as `tracklabel experiment paper`
    test_frames: int = Field(default=465, ge=10)
    crowd: float = Field(default=3.0, ge=0.1, le=10.0)  # simulator: factor on people, cyclists and moving cars
    cyclists: float = Field(default=3.0, ge=0.1, le=10.0)  # simulator: further factor on cyclists
    test_style: str = "b"  # campus style of the new scene (research.simulation.style)
    # the development scene: a new scene like D (its style and length) on which the strategy the
    # report quotes is chosen; D only scores the chosen one (the strategy is never picked on D)
    dev_seed: int = 2000
    size: int = Field(default=64, ge=8)
    min_labels: int = Field(default=30, ge=1)  # baseline_min labels per class (paper: 350)
    strategies: tuple[str, ...] = STRATEGIES
    budgets: tuple[int, ...] = Field(default=(2, 5, 10, 20), min_length=1)  # proposals per class; unknown: unknown_ratio x
    unknown_ratio: int = Field(default=5, ge=1)
    constraints: Literal["verified", "automatic", "none"] = "verified"  # D's constraints while fine-tuning
    min_track_samples: int = 3
    pretrain_evals: int = Field(default=8, ge=1)  # epochs (validation points) of each pretraining run
    pretrain_label_steps: int = Field(default=1200, ge=1)  # steps of the labels-only runs
    pretrain_pair_steps: int = Field(default=800, ge=1)  # steps of constraint100
    val_max: int = 2000  # validation samples per pretraining run (a random subset)
    balance: bool = True  # draw the anchors' classes evenly (pipeline.finetune.balance_classes)
    finetune_seeds: tuple[int, ...] = Field(default=(0,), min_length=1)  # each point: the mean over these seeds
    finetune_steps_per_epoch: int | None = Field(default=None, ge=1)  # None = the product's (smoke runs: fewer)
    seed: int = 0
    threads: int = Field(default=1, ge=0, le=256)  # torch CPU threads (0 = torch's default)

    @field_validator("strategies")
    @classmethod
    def _known_strategies(cls, v: tuple[str, ...]) -> tuple[str, ...]:
        bad = [s for s in v if s not in STRATEGIES]
        if bad or not v:
            raise ValueError(f"unknown {', '.join(bad) or 'none given'}; valid: {', '.join(STRATEGIES)}")
        return v

    @field_validator("budgets")
    @classmethod
    def _positive_budgets(cls, v: tuple[int, ...]) -> tuple[int, ...]:
        if min(v) < 1:
            raise ValueError("give budgets >= 1")
        return v

    def pretrain_config(self, with_pairs: bool) -> TrainingConfig:
        """The product's training config at this experiment's step budget."""
        steps = self.pretrain_pair_steps if with_pairs else self.pretrain_label_steps
        return TrainingConfig(epochs=self.pretrain_evals, steps_per_epoch=max(1, steps // self.pretrain_evals),
                              seed=self.seed, threads=self.threads)

    def finetune_config(self, seed: int) -> TrainingConfig:
        """The product's fine-tuning config (`TrainingConfig.finetuning`, the finetune job's)."""
        cfg = TrainingConfig(seed=seed, threads=self.threads).finetuning().for_constraints(self.constraints)
        if self.finetune_steps_per_epoch is not None:
            cfg = cfg.model_copy(update={"steps_per_epoch": self.finetune_steps_per_epoch})
        return cfg

    def key(self, scene: SceneSamples | None = None) -> str:
        """Hash of what the pretrained models depend on (they are cached under this key): these
        settings, the training configs, the training scene (its summary changes with the
        pipeline's config) and the training code."""
        fields_ = ("train_seed", "train_frames", "crowd", "cyclists", "size", "min_labels", "val_max", "seed")
        data: dict[str, Any] = {k: getattr(self, k) for k in fields_}
        data["training"] = [self.pretrain_config(p).model_dump(mode="json", exclude={"threads"}) for p in (False, True)]
        if scene is not None:
            data["scene"] = scene.summary()
        # the code that trains them: a change to the training loop, model or split makes new models
        data["code"] = code_fingerprint(("pipeline", "research/experiments/data.py", "research/experiments/finetune.py"),
                                        skip=frozenset())
        blob = json.dumps(data, sort_keys=True)
        return hashlib.sha256(blob.encode()).hexdigest()[:10]


@dataclass
class RunResult:
    name: str
    f: list[float | None]
    mean_f: float
    extra: dict[str, Any] = field(default_factory=dict)


def _f_list(report: Any) -> list[float | None]:
    return [None if not np.isfinite(v) else round(float(v), 2) for v in report.f]


def evaluate_on(model: SampleCNN, scene: SceneSamples, mask: np.ndarray | None = None, probs: np.ndarray | None = None) -> Any:
    """Per-class report of `model` on the scene's samples with a sample-class majority (and `mask`)."""
    truth = ground_truth_label(scene)
    keep = truth >= 0
    if mask is not None:
        keep &= mask
    p = predict(model, scene.samples[keep]) if probs is None else probs[keep]
    return classification_report(truth[keep], p.argmax(1), K, SAMPLE_CLASSES)


def _pretrain_sets(scene: SceneSamples, cfg: FinetuneExperimentConfig) -> dict[str, tuple[TrainingData, LabelledSamples]]:
    """Training data of the three pretrained settings and their one validation set: the route's
    labels split 70/30 by ground-truth object (`data.split_by_object`, as the paper experiment),
    no constraint touching the validation side."""
    split = split_by_object(scene, 0.3, cfg.seed, cfg.min_labels)
    va = split.val_labelled
    if len(va) > cfg.val_max:
        va = np.sort(np.random.default_rng(cfg.seed).choice(va, cfg.val_max, replace=False))
    val = LabelledSamples(scene.samples[va], scene.label[va].astype(np.int64))
    pairs = scene.verified_pairs[training_side(scene, split, scene.verified_pairs)]
    out = {}
    for name, idx, p in (("baseline_min", split.min_labelled, None), ("constraint100", split.min_labelled, pairs),
                         ("baseline_max", split.train_labelled, None)):
        out[name] = (TrainingData.build(scene.samples, idx, scene.label[idx].astype(np.int64), p), val)
    return out


def _pretrain(
    scene: SceneSamples, cfg: FinetuneExperimentConfig, models_dir: Path, log: Callable[[str], None], progress: Progress
) -> dict[str, Path]:
    paths: dict[str, Path] = {}
    mc = ModelConfig()
    sc = SampleConfig(size=cfg.size, foreground_channel=scene.samples.shape[1] == 4)
    for name, (data, val) in _pretrain_sets(scene, cfg).items():
        out = models_dir / f"{name}_{cfg.key(scene)}"
        ckpt = out / "best.pt"
        if ckpt.is_file():
            log(f"{name}: reusing {ckpt}")
            paths[name] = ckpt
            continue
        tc = cfg.pretrain_config(with_pairs=len(data.pairs) > 0)
        t0 = time.perf_counter()
        res = train(data, tc, mc, sc, val=val, checkpoint_dir=out, progress=progress)
        log(
            f"{name}: {len(data.labelled)} labels, {len(data.pairs)} pairs, val F {res.metrics.get('val', {}).get('mean_f')}"
            f" ({time.perf_counter() - t0:.0f} s)"
        )
        assert res.checkpoint is not None
        paths[name] = res.checkpoint
    return paths


def simulated_answers(
    scene: SceneSamples, index: np.ndarray, track: np.ndarray, track_level: bool
) -> tuple[np.ndarray, np.ndarray, int, int]:
    """The simulated operator's answers to proposals.

    Returns (labelled sample indices (A,), their classes (A,), confirmations, rejections).
    Sample level: each proposal's sample gets its true class, or is rejected (mostly ground or
    unlabelled). Track level: the track's samples the careful operator labels (`scene.label`),
    or a rejection when it labels none of them.
    """
    truth = ground_truth_label(scene)
    if not track_level:
        ok = truth[index] >= 0
        return index[ok].astype(np.int64), truth[index[ok]].astype(np.int64), int(ok.sum()), int((~ok).sum())
    members = np.isin(scene.track, track) & (scene.label >= 0)
    confirmed = len(np.unique(scene.track[members]))
    idx = np.flatnonzero(members)
    return idx, scene.label[idx].astype(np.int64), confirmed, len(track) - confirmed


def _curve_plot(curves: dict[str, dict[str, list]], lines: dict[str, float], path: Path) -> None:
    from pipeline.plots import _pyplot, _save

    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(6.4, 4.2))
    for name, c in curves.items():
        ax.errorbar(c["budget"], c["mean_f"], yerr=c.get("mean_f_std"), marker="o", capsize=3, label=name)
    styles = ["--", ":", "-."]
    for i, (name, v) in enumerate(lines.items()):
        ax.axhline(v, color="grey", linestyle=styles[i % len(styles)], label=f"{name} ({v:.1f})")
    ax.set_xlabel("confirmations per class (unknown: x5)")
    ax.set_ylabel("average F on the new scene")
    ax.set_title("Fine-tuning on a new scene: F against confirmations")
    ax.legend(fontsize=8, loc="lower right")
    ax.grid(alpha=0.3)
    _save(fig, path)


def _table(rows: list[RunResult]) -> str:
    head = "| Learning method | Classifier | " + " | ".join(SAMPLE_CLASSES) + " | average |"
    sep = "|" + "---|" * (K + 3)
    kinds = {"baseline_min": "sup.", "baseline_max": "sup."}

    def cell(v: float | None) -> str:
        return "-" if v is None else f"{v:.1f}"

    lines = [head, sep]
    for r in rows:
        lines.append(
            f"| {kinds.get(r.name, 'semi-sup.')} | {r.name} | " + " | ".join(cell(v) for v in r.f) + f" | {r.mean_f:.1f} |"
        )
    return "\n".join(lines)


def _one_finetune(cfg: FinetuneExperimentConfig, scene: SceneSamples, pretrained: tuple[SampleCNN, Any],
                  probs: np.ndarray, feats: np.ndarray, reference: np.ndarray, strategy: str, budget: int,
                  fseed: int) -> dict[str, Any]:
    """One fine-tuning run: proposals of `strategy`, the simulated operator's answers to `budget`
    per class, fine-tuning on them and the scene's constraints, and F on the scene: on all of it,
    and held out (without the samples the operator labelled), there beside baseline_max's F on
    the same samples (`reference`: baseline_max's class probabilities on the scene)."""
    if cfg.constraints == "automatic":
        pairs, scores, verified = scene.auto_pairs, scene.auto_scores, None
    else:
        pairs, scores, verified = scene.verified_pairs, None, None
    t0 = time.perf_counter()
    counts = class_counts(budget, cfg.unknown_ratio * budget)
    props = propose(probs, strategy, counts, features=feats, tracks=scene.track, min_track_samples=cfg.min_track_samples)
    idx, y, n_conf, n_rej = simulated_answers(scene, props.index, props.track, strategy in TRACK_STRATEGIES)
    data = finetune_data(scene.samples, idx, y, pairs, scores, verified,
                         "automatic" if cfg.constraints == "automatic" else cfg.constraints, balance=cfg.balance)
    res = finetune(pretrained, data, cfg.finetune_config(fseed))
    p_new = predict(res.model, scene.samples)
    held = np.ones(len(scene), bool)
    held[idx] = False
    rep, rep_held = evaluate_on(res.model, scene, probs=p_new), evaluate_on(res.model, scene, mask=held, probs=p_new)
    ref_held = evaluate_on(res.model, scene, mask=held, probs=reference)
    return {
        "strategy": strategy, "budget": budget, "seed": fseed, "proposals": len(props), "confirmed": n_conf,
        "rejected": n_rej, "labelled_samples": int(len(idx)), "labelled_per_class": np.bincount(y, minlength=K).tolist(),
        "pairs": int(len(data.pairs)), "f": _f_list(rep), "mean_f": round(rep.mean_f, 2),
        "held_out_f": _f_list(rep_held), "held_out_mean_f": round(rep_held.mean_f, 2),
        "held_out_baseline_max_mean_f": round(ref_held.mean_f, 2),
        "held_out_support": [int(v) for v in rep_held.support],
        "seconds": round(time.perf_counter() - t0, 1),
    }


def choose_strategy(dev_points: list[dict[str, Any]], budget: int) -> str:
    """The strategy the report quotes: the best held-out F at `budget` on the development scene
    (never on D, where it is then scored)."""
    at = [r for r in dev_points if r["budget"] == budget]
    if not at:
        raise ValueError(f"no development run at budget {budget}")
    return max(at, key=lambda r: r["held_out_mean_f"])["strategy"]


def finetune_target(points: list[dict[str, Any]], strategy: str, budget: int) -> dict[str, Any]:
    """The target on D: the chosen strategy at `budget` against baseline_max, both on D's samples
    the operator did not label (F on all of D would count the labelled samples the model was just
    fitted to)."""
    r = next(p for p in points if p["strategy"] == strategy and p["budget"] == budget)
    return {"strategy": strategy, "budget": budget, "held_out_mean_f": r["held_out_mean_f"],
            "baseline_max_held_out_mean_f": r["held_out_baseline_max_mean_f"], "mean_f_all_of_d": r["mean_f"],
            "met": r["held_out_mean_f"] >= r["held_out_baseline_max_mean_f"]}


def _curves(points: list[dict[str, Any]], strategies: tuple[str, ...]) -> dict[str, dict[str, list]]:
    """Per strategy: budgets and the mean F (all samples, held out) at each."""
    curves: dict[str, dict[str, list]] = {}
    for s in strategies:
        rs = [r for r in points if r["strategy"] == s]
        curves[s] = {k: [r[k] for r in rs] for k in ("budget", "confirmed", "labelled_samples", "mean_f", "mean_f_std",
                                                       "held_out_mean_f", "held_out_baseline_max_mean_f")}
    return curves


def _strategy_table(curves: dict[str, dict[str, list]], budgets: tuple[int, ...], seeds: int) -> list[str]:
    """Rows 'strategy | F (held out) per budget'."""
    rows = ["| strategy | " + " | ".join(str(b) for b in budgets) + " |", "|---|" + "---|" * len(budgets)]
    for s, c in curves.items():
        cells = [f"{v:.1f}" + (f" ± {sd:.1f}" if seeds > 1 else "") + f" ({h:.1f})"
                 for v, sd, h in zip(c["mean_f"], c["mean_f_std"], c["held_out_mean_f"], strict=True)]
        rows.append(f"| {s} | " + " | ".join(cells) + " |")
    return rows


def _report(out: Path, cfg: FinetuneExperimentConfig, rows: dict[str, RunResult], dev_runs: list[dict[str, Any]],
            runs: list[dict[str, Any]], scenes: dict[str, SceneSamples]) -> dict[str, Any]:
    """The experiment's JSON (without timings), finetune.md, the curve JSON and the plots."""
    from pipeline.plots import plot_f_bars

    budget = max(b for b in cfg.budgets if b <= 20) if any(b <= 20 for b in cfg.budgets) else min(cfg.budgets)
    dev_points, points = _mean_over_seeds(dev_runs), _mean_over_seeds(runs)
    chosen = choose_strategy(dev_points, budget)
    target = finetune_target(points, chosen, budget)
    ft = next(r for r in points if r["strategy"] == chosen and r["budget"] == budget)
    rows_out = [rows["baseline_min"], rows["constraint100"],
                RunResult(f"constraint100 + fine-tuning ({chosen}, {budget}/class)", ft["f"], ft["mean_f"]),
                RunResult(f"the same, held out ({sum(ft['held_out_support'])} samples the operator did not label)",
                          ft["held_out_f"], ft["held_out_mean_f"]),
                rows["baseline_max"]]
    dev_curves, curves = _curves(dev_points, cfg.strategies), _curves(points, (chosen,))
    result: dict[str, Any] = {
        "config": cfg.model_dump(mode="json"), "default_strategy": DEFAULT_STRATEGY,
        "train_scene": scenes["train"].summary(), "dev_scene": scenes["dev"].summary(),
        "test_scene": scenes["test"].summary(), "classes": list(SAMPLE_CLASSES),
        "table": [{"name": r.name, "f": r.f, "mean_f": r.mean_f} for r in rows_out],
        "pretrained": {k: {"f": v.f, "mean_f": v.mean_f, "report": v.extra["report"]} for k, v in rows.items()},
        "dev_runs": dev_runs, "dev_points": dev_points, "dev_curves": dev_curves,
        "runs": runs, "points": points, "curves": curves, "target": target | {"chosen_on": f"dev seed {cfg.dev_seed}"},
    }
    (out / "finetune_curve.json").write_text(json.dumps(
        {"dev_curves": dev_curves, "curves": curves, "baseline_max": rows["baseline_max"].mean_f,
         "constraint100": rows["constraint100"].mean_f}, indent=2))
    (out / "finetune.md").write_text("\n".join([
        "F-measure on the new scene D (Table 10 layout)", "", _table(rows_out), "",
        f"Strategy chosen on the development scene (seed {cfg.dev_seed}), the best F on its samples the operator "
        f"did not label at {budget} per class: {chosen}. On D without the samples the operator labelled: "
        f"{target['held_out_mean_f']:.1f} against baseline_max's {target['baseline_max_held_out_mean_f']:.1f} on the "
        f"same samples ({'met' if target['met'] else 'NOT met'}).", "",
        f"Development scene: average F (held out in brackets) against confirmations per class "
        f"(unknown x{cfg.unknown_ratio}), mean over fine-tuning seeds {list(cfg.finetune_seeds)}:", "",
        *_strategy_table(dev_curves, cfg.budgets, len(cfg.finetune_seeds)), "",
        "D, the chosen strategy only:", "", *_strategy_table(curves, cfg.budgets, len(cfg.finetune_seeds)), ""]))
    f_mat = np.array([[np.nan if v is None else v for v in r.f] for r in rows_out])
    plot_f_bars(f_mat, [r.name for r in rows_out], SAMPLE_CLASSES, out / "finetune_f.png", "F on the new scene")
    _curve_plot(dev_curves | {f"{chosen} on D": curves[chosen]},
                {"baseline_max on D": rows["baseline_max"].mean_f, "constraint100 on D": rows["constraint100"].mean_f,
                 "baseline_min on D": rows["baseline_min"].mean_f}, out / "finetune_curve.png")
    return result


def _finetune_runs(cfg: FinetuneExperimentConfig, scene: SceneSamples, models: dict[str, Any],
                   strategies: tuple[str, ...], what: str, progress: Progress, log: Callable[[str], None]) -> list[dict[str, Any]]:
    """Every (strategy, budget, fine-tuning seed) run on one scene, from the pretrained constraint100."""
    pre_model, pre_meta = models["constraint100"]
    probs, feats = predict(pre_model, scene.samples), embed(pre_model, scene.samples)
    reference = predict(models["baseline_max"][0], scene.samples)
    runs: list[dict[str, Any]] = []
    jobs = [(s, b, fs) for s in strategies for b in cfg.budgets for fs in cfg.finetune_seeds]
    with progress.bar(len(jobs), f"fine-tune runs ({what})", unit="run") as bar:
        for strategy, budget, fseed in jobs:
            run = _one_finetune(cfg, scene, (pre_model, pre_meta), probs, feats, reference, strategy, budget, fseed)
            runs.append(run)
            bar.update()
            log(f"{what}: {strategy} x{budget}: F {run['mean_f']:.1f}, held out {run['held_out_mean_f']:.1f} "
                f"(baseline_max {run['held_out_baseline_max_mean_f']:.1f})")
    return runs


def run_finetune_experiment(
    out: str | Path,
    cfg: FinetuneExperimentConfig | None = None,
    cache: str | Path | None = None,
    progress: Progress = QUIET,
    log: Callable[[str], None] = print,
) -> dict[str, Any]:
    """Run the experiment (module docstring) and write its outputs under `out`; returns the JSON."""
    import torch

    cfg = cfg or FinetuneExperimentConfig()
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    cache = Path(cache) if cache is not None else out / "cache"
    t_start = time.perf_counter()
    threads_before = torch.get_num_threads()
    if cfg.threads:
        torch.set_num_threads(cfg.threads)
    try:
        log(f"preparing the training route (seed {cfg.train_seed}, {cfg.train_frames} frames), the development "
            f"scene (seed {cfg.dev_seed}) and new scene D (seed {cfg.test_seed}), {cfg.test_frames} frames each")
        sim = {"crowd": cfg.crowd, "cyclists": cfg.cyclists}
        scenes = {"train": prepare_scene(cache, cfg.train_seed, cfg.train_frames, cfg.size, progress=progress, **sim)}
        for key, seed in (("dev", cfg.dev_seed), ("test", cfg.test_seed)):
            scenes[key] = prepare_scene(cache, seed, cfg.test_frames, cfg.size, progress=progress,
                                        style=cfg.test_style, **sim)
        t_data = time.perf_counter() - t_start
        paths = _pretrain(scenes["train"], cfg, out / "models", log, progress)
        models = {name: load_checkpoint(p) for name, p in paths.items()}
        rows: dict[str, RunResult] = {}
        for name, (model, _meta) in models.items():
            rep = evaluate_on(model, scenes["test"])
            rows[name] = RunResult(name, _f_list(rep), round(rep.mean_f, 2), {"report": rep.to_dict()})
            log(f"{name} on the new scene: average F {rep.mean_f:.1f}")
        dev_runs = _finetune_runs(cfg, scenes["dev"], models, cfg.strategies, "development scene", progress, log)
        budget = max(b for b in cfg.budgets if b <= 20) if any(b <= 20 for b in cfg.budgets) else min(cfg.budgets)
        chosen = choose_strategy(_mean_over_seeds(dev_runs), budget)
        runs = _finetune_runs(cfg, scenes["test"], models, (chosen,), "D", progress, log)
    finally:
        torch.set_num_threads(threads_before)

    result = _report(out, cfg, rows, dev_runs, runs, scenes)
    result["seconds"] = {"data": round(t_data, 1), "total": round(time.perf_counter() - t_start, 1)}
    (out / "finetune.json").write_text(json.dumps(result, indent=2))
    return result


def _mean_over_seeds(runs: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """One point per (strategy, budget): F per class and averages as means over its seeds."""
    out: list[dict[str, Any]] = []
    keys = list(dict.fromkeys((r["strategy"], r["budget"]) for r in runs))
    for strategy, budget in keys:
        rs = [r for r in runs if r["strategy"] == strategy and r["budget"] == budget]
        means = np.array([r["mean_f"] for r in rs])
        out.append(
            rs[0]
            | {
                "seeds": [r["seed"] for r in rs],
                "f": _nanmean_list([r["f"] for r in rs]),
                "mean_f": round(float(means.mean()), 2),
                "mean_f_std": round(float(means.std()), 2),
                "held_out_mean_f": round(float(np.mean([r["held_out_mean_f"] for r in rs])), 2),
                "held_out_baseline_max_mean_f": round(float(np.mean([r["held_out_baseline_max_mean_f"] for r in rs])), 2),
                "held_out_f": _nanmean_list([r["held_out_f"] for r in rs]),
            }
        )
    return out


def _nanmean_list(rows: list[list[float | None]]) -> list[float | None]:
    """Per-class mean over runs of F lists (None = no support), None where no run has a value."""
    f = np.array([[np.nan if v is None else v for v in r] for r in rows], np.float64)
    with np.errstate(all="ignore"):
        m = np.nanmean(f, axis=0)
    return [None if not np.isfinite(v) else round(float(v), 2) for v in m]
