"""Which model should run in the review loop: an offline replay on labelled real clips.

    python -m research.experiments.assist_heads OUT CLIP... [--reviews 50] [--heads forest,...] [--seeds 0,1,2]

For each clip (a KITTI folder with labels/ and poses), the pipeline's tracks and samples are made
once; an oracle operator then reviews, in the product's queue order (points x (1 - confidence),
`app.crud.queue_priority`), the pending track the current head ranks first, labels it with the
true majority class of its points, and every 5 reviews the head is refitted, as the assist job
does. Heads compared (all start from the shipped model):

- `cnn`: the shipped CNN, never retrained;
- `forest`: the product's head (`pipeline.assist`): a random forest on the CNN's embedding,
  probabilities and segment statistics (size, range, height and shape), fitted on the reviewed
  samples;
- `forest_without_shape`: the same without the segments' shape (`pipeline.assist.segment_shapes`);
- `forest_keeps_unseen`: the same, but the CNN keeps its probability for classes no review has
  shown yet;
- `finetune`: the CNN itself fine-tuned on the reviewed samples (`pipeline.finetune`, the
  product's fine-tuning defaults, 200 steps) and its must-link pairs.

Reported at 10, 20, 30 and 50 reviews: the share of the clip's labelled non-ground points, in
tracks, whose track's class (reviewed, else predicted) is their true class; and over the pending
tracks the share of points right among the predictions at confidence >= 0.9 (what a bulk accept
would take). Each head runs once per seed (the forest's); writes OUT/assist_heads.json.
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from pipeline.classes import GROUND, NUM_SAMPLE_CLASSES, UNLABELLED, to_ours

CHECKPOINTS = (10, 20, 30, 50)
REFIT_EVERY = 5


@dataclass(frozen=True)
class Clip:
    """A processed clip: per track its points per true class (T, 9: classes, ground, unlabelled
    last), its samples' indices, and the samples' features."""

    name: str
    counts: np.ndarray
    sample_track: np.ndarray  # (N,) index into the tracks
    features: Any  # pipeline.assist.SampleFeatures
    samples: np.ndarray  # (N, C, S, S)
    pairs: np.ndarray  # (P, 2) consecutive samples of one track
    non_ground: int  # labelled non-ground points of the clip


def _frames(path: Path) -> tuple[list[Any], Any]:
    from pipeline.config import PipelineConfig
    from pipeline.processing import SequenceProcessor
    from pipeline.sequence import open_sequence

    seq = open_sequence(path)
    return list(SequenceProcessor(PipelineConfig(), seq.sensor).iter_frames(seq.source, samples=True, poses=seq.poses)), seq


def process(path: Path) -> Clip:
    """The clip's tracks, samples and their features (the shipped model's view)."""
    from pipeline.assist import SampleFeatures, segment_shapes, segment_stats
    from pipeline.model import default_model_path, embed, load_checkpoint, predict

    frames, _ = _frames(path)
    key_counts: dict[int, np.ndarray] = {}
    ng = 0
    for fr in frames:
        t = to_ours(fr.scan.semantic)
        ng += int(((t != GROUND) & (t != UNLABELLED)).sum())
        tr = fr.track_labels().astype(np.int64)
        m = tr > 0
        cls = np.where(t[m] == UNLABELLED, NUM_SAMPLE_CLASSES + 1, t[m])
        keys, n = np.unique(tr[m] * 16 + cls, return_counts=True)
        for k, c in zip(keys, n, strict=True):
            key_counts.setdefault(int(k // 16), np.zeros(NUM_SAMPLE_CLASSES + 2, np.int64))[int(k % 16)] += c
    tracks = sorted(key_counts)
    pos = {k: i for i, k in enumerate(tracks)}
    samples = np.concatenate([fr.samples for fr in frames])
    sample_track = np.concatenate([[pos.get(int(fr.segments.track_id[s]), -1) for s in fr.sample_segment] for fr in frames])
    seg = [(fr, s) for fr in frames for s in fr.sample_segment]
    stats = segment_stats(np.array([fr.segments.n_points[s] for fr, s in seg]),
                          np.array([np.linalg.norm(fr.segments.centroid[s]) for fr, s in seg]),
                          np.array([fr.segments.centroid[s][2] for fr, s in seg]),
                          np.concatenate([segment_shapes(fr.scan.points, fr.scan.intensity, fr.segment, fr.sample_segment)
                                          for fr in frames]))
    model, _ = load_checkpoint(default_model_path())
    feats = SampleFeatures(embed(model, samples), predict(model, samples), stats)
    order = np.lexsort((np.arange(len(sample_track)), sample_track))
    same = sample_track[order][1:] == sample_track[order][:-1]
    pairs = np.stack([order[:-1][same], order[1:][same]], axis=1)
    return Clip(path.name, np.stack([key_counts[k] for k in tracks]), sample_track.astype(np.int64), feats,
                samples, pairs, ng)


def _head_probs(head: str, clip: Clip, labelled: np.ndarray, labels: np.ndarray, seed: int) -> np.ndarray:
    """(N, K) class probabilities of the samples after a refit of `head` on the reviewed samples."""
    from pipeline.assist import SampleFeatures, assist_probs

    feats = clip.features
    if head == "cnn" or len(np.unique(labels)) < 2:
        return feats.probs
    if head == "forest":
        return assist_probs(feats, labelled, labels, NUM_SAMPLE_CLASSES, seed=seed)[:, :NUM_SAMPLE_CLASSES]
    if head == "forest_without_shape":  # constant columns: the forest never splits on them
        stats = feats.stats.copy()
        stats[:, 3:] = 0.0
        plain = SampleFeatures(feats.embedding, feats.probs, stats)
        return assist_probs(plain, labelled, labels, NUM_SAMPLE_CLASSES, seed=seed)[:, :NUM_SAMPLE_CLASSES]
    if head == "forest_keeps_unseen":
        forest = assist_probs(feats, labelled, labels, NUM_SAMPLE_CLASSES, seed=seed)[:, :NUM_SAMPLE_CLASSES]
        unseen = np.setdiff1d(np.arange(NUM_SAMPLE_CLASSES), labels)
        out = forest * (1.0 - feats.probs[:, unseen].sum(axis=1, keepdims=True))
        out[:, unseen] = feats.probs[:, unseen]
        return out
    return _finetuned(clip, labelled, labels)


def _finetuned(clip: Clip, labelled: np.ndarray, labels: np.ndarray) -> np.ndarray:
    from pipeline.config import TrainingConfig
    from pipeline.finetune import finetune, finetune_data
    from pipeline.model import default_model_path, predict

    reviewed = np.isin(clip.pairs, labelled).all(axis=1)
    data = finetune_data(clip.samples, labelled, labels, clip.pairs[reviewed], constraints="verified", balance=True)
    cfg = TrainingConfig().finetuning().model_copy(update={"epochs": 2, "steps_per_epoch": 100})
    return predict(finetune(default_model_path(), data, cfg).model, clip.samples)


def _score(clip: Clip, decided: np.ndarray, probs: np.ndarray) -> dict[str, float]:
    from pipeline.assist import track_means

    mean, n = track_means(probs, clip.sample_track, len(clip.counts))
    cls = np.where(decided >= 0, decided, mean.argmax(axis=1))
    right = clip.counts[np.arange(len(cls)), np.minimum(cls, clip.counts.shape[1] - 1)] * (cls < NUM_SAMPLE_CLASSES)
    bulk = (decided < 0) & (n > 0) & (mean.max(axis=1) >= 0.9)
    labelled = clip.counts[:, : GROUND + 1].sum(axis=1)
    return {"non_ground_right": round(float(right.sum()) / clip.non_ground, 4),
            "bulk_share": round(float(labelled[bulk].sum()) / clip.non_ground, 4),
            "bulk_right": round(float(right[bulk].sum()) / max(float(labelled[bulk].sum()), 1.0), 4)}


def replay(clip: Clip, head: str, reviews: int, seed: int = 0) -> dict[str, Any]:
    """The oracle operator's replay with one head (module docstring)."""
    from pipeline.assist import track_means

    decided = np.full(len(clip.counts), -1, np.int64)
    truth = clip.counts[:, : GROUND + 1].argmax(axis=1)
    points = clip.counts.sum(axis=1)
    probs, out, t0 = clip.features.probs, {}, time.perf_counter()
    for r in range(1, reviews + 1):
        mean, n = track_means(probs, clip.sample_track, len(clip.counts))
        priority = np.where(n > 0, points * (1.0 - mean.max(axis=1)), points).astype(float)
        priority[decided >= 0] = -1.0
        decided[int(priority.argmax())] = truth[int(priority.argmax())]
        if r % REFIT_EVERY == 0:
            labelled = np.flatnonzero((clip.sample_track >= 0) & (decided[clip.sample_track] >= 0)
                                      & (decided[clip.sample_track] < NUM_SAMPLE_CLASSES))
            probs = _head_probs(head, clip, labelled, decided[clip.sample_track[labelled]], seed)
        if r in CHECKPOINTS:
            out[str(r)] = _score(clip, np.where(decided == GROUND, NUM_SAMPLE_CLASSES, decided), probs)
    return {"checkpoints": out, "seconds": round(time.perf_counter() - t0, 1)}


HEADS = ("cnn", "forest", "forest_without_shape", "forest_keeps_unseen", "finetune")


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out", type=Path)
    ap.add_argument("clips", type=Path, nargs="+")
    ap.add_argument("--reviews", type=int, default=max(CHECKPOINTS))
    ap.add_argument("--heads", default=",".join(HEADS), help="comma-separated, of: " + ", ".join(HEADS))
    ap.add_argument("--seeds", default="0", help="comma-separated forest seeds")
    args = ap.parse_args(argv)
    heads, seeds = args.heads.split(","), [int(s) for s in args.seeds.split(",")]
    if unknown := set(heads) - set(HEADS):
        ap.error(f"unknown heads {sorted(unknown)}")
    result: dict[str, Any] = {}
    for path in args.clips:
        clip = process(path)
        result[clip.name] = {f"{head} seed {seed}": replay(clip, head, args.reviews, seed) for head in heads for seed in seeds}
        print(clip.name, json.dumps({h: r["checkpoints"] for h, r in result[clip.name].items()}))
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "assist_heads.json").write_text(json.dumps(result, indent=1))


if __name__ == "__main__":
    main()
