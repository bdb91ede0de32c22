"""`tracklabel experiment finetune`: the paper's Table 10 protocol on the paper experiment's scenes,
with what a product operator would have reviewed.

1. Prepare the paper experiment's training route (seed `train_seed`, campus style `train_style`,
   a+), a development scene (seed `dev_seed`) and new scenes D (seeds `test_seeds`; both of the
   paper's D style `test_style`, b+: other cars, trees, shrubs and clothes) with
   `research.experiments.data` (simulation, the real perception pipeline, and a
   ground-truth-checking operator who gives labels and verified constraints).
2. Pretrain on the route with the paper experiment's data (`paper.split_scene`, 70/30 by
   ground-truth object, one validation set for all three; `paper.setting_data`):
   - baseline_min: `min_labels` labelled samples per class of the training side (the paper: 350);
   - constraint100: baseline_min's labels + every verified constraint of the training side
     (track links, of unknown tracks too, and confirmed stitches: the paper experiment's);
   - baseline_max: every label of the training side.
3. On the development scene, fine-tune constraint100 for each anchor strategy and each budget b
   (proposals per class, `unknown_ratio` x b for unknown: the paper's 20 / 100 at b = 20). A
   simulated operator answers each proposal from ground truth: a sample-level proposal gets its
   sample's true class (or is rejected when the sample is mostly ground / unlabelled); a
   track-level proposal labels the track as the careful operator of `data` would (accepted and
   truncated at its first wrong link; rejected when nothing of it survives). The scene's verified
   constraints come only from the tracks the operator reviewed (`reviewed_constraints`): the
   confirmed anchors' tracks (a sample-level anchor accepts no track, as in the product, so it
   brings none). The strategy with the best F on the development scene's samples the operator did
   not label, at the largest budget <= 20, is the one reported (`choose_strategy`).
4. Fine-tune with that strategy on each D at each budget, and with each review budget R of
   `review_budgets` too: the operator has then reviewed R tracks of D, the anchors' and others
   drawn at random (`reviewed_tracks`), whose labels and constraints the fine-tuning takes, as the
   product's finetune job takes every labelled track of the sequence. Every model is evaluated on
   all of D's samples whose majority is a sample class: per-class F (the paper's Table 10 rows),
   and the fine-tuned ones also on D without the samples the operator labelled (held out), beside
   baseline_max's F on the same samples (`finetune_target`); `seed_spread` gives the mean
   [range] over D's seeds.

Writes under `out`: finetune.json (everything), finetune.md (the spread, the Table 10 layout as
means over D's seeds, per-seed rows), finetune_f.png (per-class F bars), finetune_curve.png /
finetune_curve.json (each strategy's held-out F on the development scene and the chosen one's on
each D against the number of confirmations per class).
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
from research.experiments.data import SceneSamples, code_fingerprint, ground_truth_label, prepare_scene
from research.experiments.paper import setting_data, split_scene, verified_constraints
from research.experiments.paper_config import PaperConfig

K = NUM_SAMPLE_CLASSES
UNKNOWN = K - 1
_PAPER = PaperConfig()


class FinetuneExperimentConfig(BaseModel):
    """Sizes of the experiment (named variants: research/configs/finetune-*.yaml). `finetune-seeds`
    (16 fine-tuning runs of 40-160 s each, one torch thread) took 41 minutes on the shared 2-core
    machine, pretraining included; the defaults run 24. Pretraining and fine-tuning train with the
    product's defaults: `TrainingConfig()` and `TrainingConfig().finetuning()` (the REST train and
    finetune jobs' configs)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    train_seed: int = _PAPER.seed
    # the new scenes D; 1000: `tracklabel experiment paper`'s D. Several: the report gives the
    # mean [range] over them (the pretrained models and the chosen strategy are the same for all)
    test_seeds: tuple[int, ...] = Field(default=(_PAPER.seed + 1000,), min_length=1)
    train_frames: int = Field(default=_PAPER.frames, ge=20)  # the paper experiment's route and new scene
    test_frames: int = Field(default=_PAPER.test_frames, ge=10)
    crowd: float = Field(default=_PAPER.crowd, ge=0.1, le=10.0)  # simulator: factor on people, cyclists, moving cars
    cyclists: float = Field(default=_PAPER.cyclists, ge=0.1, le=10.0)  # simulator: further factor on cyclists
    train_style: str = _PAPER.train_style  # campus style of the route (research.simulation.style)
    test_style: str = _PAPER.test_style  # of the development scene and D
    unknown_constraints: bool = _PAPER.unknown_constraints  # the links of unknown tracks are constraints too
    # the development scene: a new scene like D (its style and length) on which the strategy the
    # report quotes is chosen; D only scores the chosen one (the strategy is never picked on D)
    dev_seed: int = 2000
    size: int = Field(default=_PAPER.size, ge=8)
    min_labels: int = Field(default=_PAPER.labels_per_class, ge=1)  # baseline_min labels per class (paper: 350)
    strategies: tuple[str, ...] = STRATEGIES
    budgets: tuple[int, ...] = Field(default=(2, 5, 10, 20), min_length=1)  # proposals per class; unknown: unknown_ratio x
    unknown_ratio: int = Field(default=5, ge=1)
    # D's constraints while fine-tuning: verified ones of the reviewed tracks only, or the
    # association's (every link, weighted by its score: no review needed), or none
    constraints: Literal["verified", "automatic", "none"] = "verified"
    # further runs on D where the operator reviewed this many tracks (the anchors' included)
    review_budgets: tuple[int, ...] = ()
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

    @field_validator("budgets", "review_budgets")
    @classmethod
    def _positive_budgets(cls, v: tuple[int, ...]) -> tuple[int, ...]:
        if v and min(v) < 1:
            raise ValueError("give budgets >= 1")
        return v

    @property
    def report_budget(self) -> int:
        """The budget the report quotes and the strategy is chosen at: the largest <= 20."""
        return max(b for b in self.budgets if b <= 20) if any(b <= 20 for b in self.budgets) else min(self.budgets)

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

    def paper_config(self) -> PaperConfig:
        """The paper experiment's config of this route's split and pretraining data."""
        return PaperConfig(seed=self.seed, labels_per_class=self.min_labels, unknown_constraints=self.unknown_constraints)

    def key(self, scene: SceneSamples | None = None) -> str:
        """Hash of what the pretrained models depend on (they are cached under this key): these
        settings, the training configs, the training scene (its summary changes with the
        pipeline's config) and the training code."""
        fields_ = ("train_seed", "train_frames", "crowd", "cyclists", "train_style", "unknown_constraints", "size",
                   "min_labels", "val_max", "seed")
        data: dict[str, Any] = {k: getattr(self, k) for k in fields_}
        data["training"] = [self.pretrain_config(p).model_dump(mode="json", exclude={"threads"}) for p in (False, True)]
        if scene is not None:
            data["scene"] = scene.summary()
        # the code that trains them: a change to the training loop, model or split makes new models
        data["code"] = code_fingerprint(("pipeline", "research/experiments/data.py", "research/experiments/paper.py",
                                         "research/experiments/paper_config.py", "research/experiments/finetune.py"),
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
    """Training data of the three pretrained settings and their one validation set: the paper
    experiment's split and data (`paper.split_scene`, `paper.setting_data`), no constraint touching
    the validation side."""
    paper = cfg.paper_config()
    split = split_scene(scene, paper)
    va = split.val_labelled
    if len(va) > cfg.val_max:
        va = np.sort(np.random.default_rng(cfg.seed).choice(va, cfg.val_max, replace=False))
    val = LabelledSamples(scene.samples[va], scene.label[va].astype(np.int64))
    out = {}
    for name in ("baseline_min", "constraint100", "baseline_max"):
        idx, pairs, weights = setting_data(name, scene, split, paper.unknown_constraints)
        out[name] = (TrainingData.build(scene.samples, idx, scene.label[idx].astype(np.int64), pairs, weights), val)
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


def reviewed_tracks(scene: SceneSamples, anchor_tracks: np.ndarray, review_budget: int | None, min_samples: int,
                    seed: int) -> np.ndarray:
    """Tracks the simulated operator reviewed: the anchors' tracks; with a review budget R, also
    other tracks of at least `min_samples` samples drawn at random until R tracks are reviewed
    (fewer when the scene has no more)."""
    anchors = np.unique(np.asarray(anchor_tracks, np.int64))
    if review_budget is None or review_budget <= len(anchors):
        return anchors
    ids, n = np.unique(scene.track, return_counts=True)
    pool = ids[(n >= min_samples) & ~np.isin(ids, anchors)]
    take = min(review_budget - len(anchors), len(pool))
    extra = np.random.default_rng(seed).choice(pool, take, replace=False)
    return np.sort(np.concatenate([anchors, extra])).astype(np.int64)


def reviewed_constraints(scene: SceneSamples, pairs: np.ndarray, tracks: np.ndarray) -> np.ndarray:
    """(P', 2) the `pairs` both of whose samples lie on reviewed `tracks`: in the product a verified
    constraint exists only inside (or, a stitch, between) tracks an operator accepted."""
    if len(pairs) == 0:
        return np.zeros((0, 2), np.int64)
    return pairs[np.isin(scene.track[pairs], tracks).all(axis=1)].astype(np.int64)


def _curve_plot(curves: dict[str, dict[str, list]], lines: dict[str, float], path: Path) -> None:
    from pipeline.plots import _pyplot, _save

    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(6.4, 4.2))
    for name, c in curves.items():
        ax.plot(c["budget"], c["held_out_mean_f"], marker="o", label=name)
    styles = ["--", ":", "-."]
    for i, (name, v) in enumerate(lines.items()):
        ax.axhline(v, color="grey", linestyle=styles[i % len(styles)], label=f"{name} ({v:.1f})")
    ax.set_xlabel("confirmations per class (unknown: x5)")
    ax.set_ylabel("average F, samples the operator did not label")
    ax.set_title("Fine-tuning on a new scene: held-out F against confirmations")
    ax.legend(fontsize=7, loc="lower right")
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


@dataclass
class _Scored:
    """A scene with the pretrained models' outputs on it."""

    scene: SceneSamples
    probs: np.ndarray  # constraint100's class probabilities (the proposals')
    feats: np.ndarray  # constraint100's features (diverse strategies)
    reference: np.ndarray  # baseline_max's class probabilities (the held-out comparison)
    pairs: np.ndarray  # every verified constraint of the scene (before the review rule)


def _score_scene(scene: SceneSamples, models: dict[str, Any], cfg: FinetuneExperimentConfig) -> _Scored:
    model = models["constraint100"][0]
    return _Scored(scene, predict(model, scene.samples), embed(model, scene.samples),
                   predict(models["baseline_max"][0], scene.samples),
                   verified_constraints(scene, cfg.unknown_constraints))


def _one_finetune(cfg: FinetuneExperimentConfig, scored: _Scored, pretrained: tuple[SampleCNN, Any], strategy: str,
                  budget: int, review_budget: int | None, fseed: int) -> dict[str, Any]:
    """One fine-tuning run: proposals of `strategy`, the simulated operator's answers to `budget`
    per class (and, with `review_budget`, its review of that many tracks), fine-tuning on them and
    the reviewed tracks' constraints, and F on the scene: on all of it, and held out (without the
    samples the operator labelled), there beside baseline_max's F on the same samples."""
    scene = scored.scene
    t0 = time.perf_counter()
    counts = class_counts(budget, cfg.unknown_ratio * budget)
    props = propose(scored.probs, strategy, counts, features=scored.feats, tracks=scene.track,
                    min_track_samples=cfg.min_track_samples)
    idx, y, n_conf, n_rej = simulated_answers(scene, props.index, props.track, strategy in TRACK_STRATEGIES)
    # a sample-level anchor labels one sample and accepts no track
    anchor_tracks = np.unique(scene.track[idx]) if strategy in TRACK_STRATEGIES else np.zeros(0, np.int64)
    tracks = reviewed_tracks(scene, anchor_tracks, review_budget, cfg.min_track_samples, fseed)
    extra = np.flatnonzero(np.isin(scene.track, np.setdiff1d(tracks, anchor_tracks)) & (scene.label >= 0))
    idx, y = np.concatenate([idx, extra]), np.concatenate([y, scene.label[extra].astype(np.int64)])
    if cfg.constraints == "automatic":  # the association's links: no review needed
        data = finetune_data(scene.samples, idx, y, scene.auto_pairs, scene.auto_scores, None, "automatic",
                             balance=cfg.balance)
    else:
        data = finetune_data(scene.samples, idx, y, reviewed_constraints(scene, scored.pairs, tracks), None, None,
                             cfg.constraints, balance=cfg.balance)
    res = finetune(pretrained, data, cfg.finetune_config(fseed))
    p_new = predict(res.model, scene.samples)
    held = np.ones(len(scene), bool)
    held[idx] = False
    rep, rep_held = evaluate_on(res.model, scene, probs=p_new), evaluate_on(res.model, scene, mask=held, probs=p_new)
    ref_held = evaluate_on(res.model, scene, mask=held, probs=scored.reference)
    return {
        "strategy": strategy, "budget": budget, "review_budget": review_budget, "seed": fseed,
        "proposals": len(props), "confirmed": n_conf, "rejected": n_rej, "reviewed_tracks": int(len(tracks)),
        "labelled_samples": int(len(np.unique(idx))), "labelled_per_class": np.bincount(y, minlength=K).tolist(),
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


def finetune_target(points: list[dict[str, Any]], strategy: str, budget: int,
                    review_budget: int | None = None) -> dict[str, Any]:
    """The target on one D: the chosen strategy at `budget` against baseline_max, both on D's
    samples the operator did not label (F on all of D would count the labelled samples the model
    was just fitted to)."""
    r = next(p for p in points if p["strategy"] == strategy and p["budget"] == budget
             and p.get("review_budget") == review_budget)
    return {"strategy": strategy, "budget": budget, "review_budget": review_budget,
            "held_out_mean_f": r["held_out_mean_f"], "baseline_max_held_out_mean_f": r["held_out_baseline_max_mean_f"],
            "gain": round(r["held_out_mean_f"] - r["held_out_baseline_max_mean_f"], 2),
            "mean_f_all_of_d": r["mean_f"], "met": r["held_out_mean_f"] >= r["held_out_baseline_max_mean_f"]}


def _spread(values: list[float]) -> dict[str, Any]:
    v = np.asarray(values, np.float64)
    return {"mean": round(float(v.mean()), 2), "min": round(float(v.min()), 2), "max": round(float(v.max()), 2),
            "values": [round(float(x), 2) for x in v]}


def seed_spread(targets: dict[int, list[dict[str, Any]]]) -> list[dict[str, Any]]:
    """Per (review budget, budget): the fine-tuned model's held-out F, baseline_max's on the same
    samples and their difference, each as mean, min, max and per-seed values over D's seeds
    (`targets`: D seed -> its `finetune_target`s), and on how many seeds the target holds."""
    keys = list(dict.fromkeys((t["review_budget"], t["budget"]) for ts in targets.values() for t in ts))
    out = []
    for review, budget in keys:
        at = [next(t for t in ts if (t["review_budget"], t["budget"]) == (review, budget)) for ts in targets.values()]
        out.append({"review_budget": review, "budget": budget, "seeds": list(targets),
                    "finetuned": _spread([t["held_out_mean_f"] for t in at]),
                    "baseline_max": _spread([t["baseline_max_held_out_mean_f"] for t in at]),
                    "gain": _spread([t["gain"] for t in at]), "met": sum(t["met"] for t in at)})
    return out


def _curves(points: list[dict[str, Any]], strategies: tuple[str, ...],
            review_budget: int | None = None) -> dict[str, dict[str, list]]:
    """Per strategy: budgets and the mean F (all samples, held out) at each."""
    curves: dict[str, dict[str, list]] = {}
    for s in strategies:
        rs = [r for r in points if r["strategy"] == s and r["review_budget"] == review_budget]
        curves[s] = {k: [r[k] for r in rs] for k in ("budget", "confirmed", "labelled_samples", "pairs", "mean_f",
                                                       "mean_f_std", "held_out_mean_f", "held_out_baseline_max_mean_f")}
    return curves


def _strategy_table(curves: dict[str, dict[str, list]], budgets: tuple[int, ...], seeds: int) -> list[str]:
    """Rows 'strategy | F (held out) per budget'."""
    rows = ["| strategy | " + " | ".join(str(b) for b in budgets) + " |", "|---|" + "---|" * len(budgets)]
    for s, c in curves.items():
        cells = [f"{v:.1f}" + (f" ± {sd:.1f}" if seeds > 1 else "") + f" ({h:.1f}, {p} pairs)"
                 for v, sd, h, p in zip(c["mean_f"], c["mean_f_std"], c["held_out_mean_f"], c["pairs"], strict=True)]
        rows.append(f"| {s} | " + " | ".join(cells) + " |")
    return rows


def _protocol(review: int | None) -> str:
    return "reviewed anchors only" if review is None else f"review budget {review} tracks"


def protocol_sentence(cfg: FinetuneExperimentConfig, chosen: str) -> str:
    """The protocol in one sentence (the report's and the README's), then the review-budget variant."""
    out = (f"constraint100, pretrained on the paper experiment's route (seed {cfg.train_seed}, style "
           f"{cfg.train_style}), is fine-tuned on new scenes D (style {cfg.test_style}, seeds "
           f"{', '.join(map(str, cfg.test_seeds))}) from {chosen} anchors (the strategy chosen on development scene "
           f"{cfg.dev_seed}) answered by a simulated operator and D's verified constraints inside the tracks that "
           "operator confirmed, no others, and scored on D's samples the operator did not label against "
           "baseline_max on the same samples.")
    if cfg.review_budgets:
        out += (f" Variant with a review budget: the operator has reviewed {' or '.join(map(str, cfg.review_budgets))} "
                "tracks of D (the anchors' and others drawn at random), and fine-tuning adds their labels and "
                "constraints, as the finetune job takes every labelled track of a sequence.")
    return out


def _spread_table(spread: list[dict[str, Any]]) -> list[str]:
    rows = ["| protocol | confirmations per class | fine-tuned, held out | baseline_max, same samples | difference | "
            "met on | per seed (fine-tuned − baseline_max) |", "|---|---|---|---|---|---|---|"]

    def mr(s: dict[str, Any], signed: bool = False) -> str:
        f = "{:+.1f}" if signed else "{:.1f}"
        return f"{f.format(s['mean'])} [{f.format(s['min'])}, {f.format(s['max'])}]"

    for s in spread:
        per = ", ".join(f"{seed}: {f:.1f} − {b:.1f}" for seed, f, b in
                        zip(s["seeds"], s["finetuned"]["values"], s["baseline_max"]["values"], strict=True))
        rows.append(f"| {_protocol(s['review_budget'])} | {s['budget']} | {mr(s['finetuned'])} | "
                    f"{mr(s['baseline_max'])} | {mr(s['gain'], True)} | {s['met']} of {len(s['seeds'])} | {per} |")
    return rows


def _mean_rows(per_seed: dict[int, dict[str, RunResult]], ft: dict[int, dict[str, Any]], chosen: str,
               budget: int) -> list[RunResult]:
    """The Table 10 rows as means over D's seeds: the pretrained models and the chosen strategy at
    `budget` with the reviewed anchors only (all of D, and held out)."""
    def mean(name: str, fs: list[list[float | None]], ms: list[float]) -> RunResult:
        return RunResult(name, _nanmean_list(fs), round(float(np.mean(ms)), 2))

    rows = [mean(n, [r[n].f for r in per_seed.values()], [r[n].mean_f for r in per_seed.values()])
            for n in ("baseline_min", "constraint100")]
    rows.append(mean(f"constraint100 + fine-tuning ({chosen}, {budget}/class)", [p["f"] for p in ft.values()],
                     [p["mean_f"] for p in ft.values()]))
    rows.append(mean("the same, held out (D's samples the operator did not label)",
                     [p["held_out_f"] for p in ft.values()], [p["held_out_mean_f"] for p in ft.values()]))
    rows.append(mean("baseline_max", [r["baseline_max"].f for r in per_seed.values()],
                     [r["baseline_max"].mean_f for r in per_seed.values()]))
    return rows


def _report(out: Path, cfg: FinetuneExperimentConfig, rows: dict[int, dict[str, RunResult]],
            dev_runs: list[dict[str, Any]], runs: dict[int, list[dict[str, Any]]],
            scenes: dict[str, Any]) -> dict[str, Any]:
    """The experiment's JSON (without timings), finetune.md, the curve JSON and the plots."""
    from pipeline.plots import plot_f_bars

    budget = cfg.report_budget
    dev_points = _mean_over_seeds(dev_runs)
    points = {seed: _mean_over_seeds(rs) for seed, rs in runs.items()}
    chosen = choose_strategy(dev_points, budget)
    reviews: tuple[int | None, ...] = (None, *cfg.review_budgets)
    targets = {seed: [finetune_target(ps, chosen, b, r) for r in reviews for b in cfg.budgets]
               for seed, ps in points.items()}
    spread = seed_spread(targets)
    ft = {seed: next(p for p in ps if p["strategy"] == chosen and p["budget"] == budget and p["review_budget"] is None)
          for seed, ps in points.items()}
    rows_out = _mean_rows(rows, ft, chosen, budget)
    dev_curves = _curves(dev_points, cfg.strategies)
    curves = {f"{chosen} on D {seed}, {_protocol(r)}": _curves(ps, (chosen,), r)[chosen]
              for seed, ps in points.items() for r in reviews}
    sentence = protocol_sentence(cfg, chosen)
    result: dict[str, Any] = {
        "config": cfg.model_dump(mode="json"), "default_strategy": DEFAULT_STRATEGY, "protocol": sentence,
        "train_scene": scenes["train"].summary(), "dev_scene": scenes["dev"].summary(),
        "test_scenes": {str(s): sc.summary() for s, sc in scenes["test"].items()}, "classes": list(SAMPLE_CLASSES),
        "chosen": {"strategy": chosen, "budget": budget, "on": f"dev seed {cfg.dev_seed}"},
        "spread": spread, "targets": {str(s): t for s, t in targets.items()},
        "table_mean_over_seeds": [{"name": r.name, "f": r.f, "mean_f": r.mean_f} for r in rows_out],
        "pretrained": {str(s): {k: {"f": v.f, "mean_f": v.mean_f, "report": v.extra["report"]} for k, v in rs.items()}
                       for s, rs in rows.items()},
        "dev_runs": dev_runs, "dev_points": dev_points, "dev_curves": dev_curves,
        "runs": {str(s): rs for s, rs in runs.items()}, "points": {str(s): ps for s, ps in points.items()},
        "curves": curves,
    }
    bmax = float(np.mean([r["baseline_max"].mean_f for r in rows.values()]))
    (out / "finetune_curve.json").write_text(json.dumps({"dev_curves": dev_curves, "curves": curves}, indent=2))
    per_seed = ["| D seed | baseline_min | constraint100 | baseline_max | D's samples | samples labelled (reviewed "
                "anchors only, " + f"{budget}/class) |", "|---|---|---|---|---|---|"]
    for seed, rs in rows.items():
        support = sum(c["support"] for c in rs["baseline_max"].extra["report"]["per_class"].values())
        per_seed.append(f"| {seed} | {rs['baseline_min'].mean_f:.1f} | {rs['constraint100'].mean_f:.1f} | "
                        f"{rs['baseline_max'].mean_f:.1f} | {support} | {ft[seed]['labelled_samples']} |")
    seeds_txt = f"over D's seeds {', '.join(map(str, cfg.test_seeds))}"
    (out / "finetune.md").write_text("\n".join([
        "Fine-tuning on a new scene D, as the product would run it", "", f"**Protocol.** {sentence}", "",
        f"Average F on D's samples the operator did not label, mean [min, max] {seeds_txt} "
        f"(one fine-tuning seed per point: {list(cfg.finetune_seeds)}):", "", *_spread_table(spread), "",
        f"Table 10 layout, F per class, mean {seeds_txt}:", "", _table(rows_out), "",
        "Pretrained models on each D (average F on all of D's samples with a sample-class majority):", "",
        *per_seed, "",
        f"Development scene (seed {cfg.dev_seed}), reviewed anchors only: average F on all of it (held out, pairs "
        f"trained on) against confirmations per class (unknown x{cfg.unknown_ratio}); chosen at {budget}: "
        f"{chosen}:", "", *_strategy_table(dev_curves, cfg.budgets, len(cfg.finetune_seeds)), "",
        *[line for seed, ps in points.items() for r in reviews for line in
          (f"D {seed}, {chosen}, {_protocol(r)}:", "", *_strategy_table(_curves(ps, (chosen,), r), cfg.budgets,
                                                                         len(cfg.finetune_seeds)), "")]]))
    f_mat = np.array([[np.nan if v is None else v for v in r.f] for r in rows_out])
    plot_f_bars(f_mat, [r.name for r in rows_out], SAMPLE_CLASSES, out / "finetune_f.png",
                f"F on the new scene, mean {seeds_txt}")
    _curve_plot({f"{s} on dev {cfg.dev_seed}": c for s, c in dev_curves.items()} | curves,
                {f"baseline_max on D (mean {seeds_txt})": bmax}, out / "finetune_curve.png")
    return result


def _finetune_runs(cfg: FinetuneExperimentConfig, scored: _Scored, models: dict[str, Any],
                   strategies: tuple[str, ...], reviews: tuple[int | None, ...], what: str, progress: Progress,
                   log: Callable[[str], None]) -> list[dict[str, Any]]:
    """Every (strategy, review budget, budget, fine-tuning seed) run on one scene, from the
    pretrained constraint100."""
    runs: list[dict[str, Any]] = []
    jobs = [(s, r, b, fs) for s in strategies for r in reviews for b in cfg.budgets for fs in cfg.finetune_seeds]
    with progress.bar(len(jobs), f"fine-tune runs ({what})", unit="run") as bar:
        for strategy, review, budget, fseed in jobs:
            run = _one_finetune(cfg, scored, models["constraint100"], strategy, budget, review, fseed)
            runs.append(run)
            bar.update()
            log(f"{what}: {strategy} x{budget}, {_protocol(review)}: {run['pairs']} pairs, F {run['mean_f']:.1f}, "
                f"held out {run['held_out_mean_f']:.1f} (baseline_max {run['held_out_baseline_max_mean_f']:.1f}; "
                f"{run['seconds']:.0f} s)")
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
        log(f"preparing the training route (seed {cfg.train_seed}, {cfg.train_frames} frames, style {cfg.train_style}),"
            f" the development scene (seed {cfg.dev_seed}) and new scenes D (seeds {list(cfg.test_seeds)}), "
            f"{cfg.test_frames} frames each, style {cfg.test_style}")
        sim = {"crowd": cfg.crowd, "cyclists": cfg.cyclists}

        def new_scene(seed: int) -> SceneSamples:
            return prepare_scene(cache, seed, cfg.test_frames, cfg.size, progress=progress, style=cfg.test_style, **sim)

        scenes: dict[str, Any] = {
            "train": prepare_scene(cache, cfg.train_seed, cfg.train_frames, cfg.size, progress=progress,
                                   style=cfg.train_style, **sim),
            "dev": new_scene(cfg.dev_seed), "test": {s: new_scene(s) for s in cfg.test_seeds}}
        t_data = time.perf_counter() - t_start
        paths = _pretrain(scenes["train"], cfg, out / "models", log, progress)
        models = {name: load_checkpoint(p) for name, p in paths.items()}
        dev_runs = _finetune_runs(cfg, _score_scene(scenes["dev"], models, cfg), models, cfg.strategies, (None,),
                                  "development scene", progress, log)
        chosen = choose_strategy(_mean_over_seeds(dev_runs), cfg.report_budget)
        rows: dict[int, dict[str, RunResult]] = {}
        runs: dict[int, list[dict[str, Any]]] = {}
        for seed, scene in scenes["test"].items():
            rows[seed] = {}
            for name, (model, _meta) in models.items():
                rep = evaluate_on(model, scene)
                rows[seed][name] = RunResult(name, _f_list(rep), round(rep.mean_f, 2), {"report": rep.to_dict()})
                log(f"{name} on D {seed}: average F {rep.mean_f:.1f}")
            runs[seed] = _finetune_runs(cfg, _score_scene(scene, models, cfg), models, (chosen,),
                                        (None, *cfg.review_budgets), f"D {seed}", progress, log)
    finally:
        torch.set_num_threads(threads_before)

    result = _report(out, cfg, rows, dev_runs, runs, scenes)
    result["seconds"] = {"data": round(t_data, 1), "total": round(time.perf_counter() - t_start, 1)}
    (out / "finetune.json").write_text(json.dumps(result, indent=2))
    return result


def _mean_over_seeds(runs: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """One point per (strategy, review budget, budget): F per class and averages as means over its
    fine-tuning seeds."""
    out: list[dict[str, Any]] = []
    keys = list(dict.fromkeys((r["strategy"], r["review_budget"], r["budget"]) for r in runs))
    for key in keys:
        rs = [r for r in runs if (r["strategy"], r["review_budget"], r["budget"]) == key]
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
