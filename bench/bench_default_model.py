"""The shipped default model (pipeline/models/default.pt, trained on the simulated campus only)
on real scans: SemanticKITTI sequence 00 (HDL-64E), frames 0-2 (the labelled frames) and 3-29
(labels carried from frames 0-2 through the poses).

    python -m bench.run_all --only default_model

1. `tracklabel predict` with no --model (the default model): point IoU per class against the
   labels of frames 0-2 (segmentation errors and unclassified points count against it).
2. Sample level, as the experiments score models: every valid segment whose points are mostly
   one of the model's classes (`research.experiments.data.process_scene`: the majority class of
   its points), classified by the model: per-class F and mean F, on frames 0-2 ("samples") and
   on frames 3-29 ("propagated"). The propagated labels (`bench.real_data.propagated_labels`)
   cover the static surfaces frames 0-2 saw, from the viewpoints of 27 later frames: more views of
   the same street, so a development check that is less noisy than three frames, not an
   independent test. Carried from frame 0 to frames 1 and 2 they agree with the real labels on
   96-98 % of the non-ground points.
Skipped when ../shared/data/real is absent.
"""

from __future__ import annotations

import json
import tempfile
from pathlib import Path

import numpy as np

from bench.real_data import REAL, kitti_seq00, kitti_seq00_propagated

LABELLED = range(3)
PROPAGATED = range(3, 30)
RADIUS = 0.2  # metres: a carried label's nearest labelled point in the world frame


def _report(model, samples: np.ndarray, truth: np.ndarray, k: int) -> dict:
    from pipeline.classes import SAMPLE_CLASSES
    from pipeline.training import LabelledSamples, evaluate

    d = evaluate(model, LabelledSamples(samples, truth.astype(np.int64))).to_dict()
    return {"samples": int(len(truth)), "mean_f": round(d["mean_f"], 2), "accuracy": round(d["accuracy"], 2),
            "per_class": {c: {"f": d["per_class"][c]["f"], "support": d["per_class"][c]["support"]}
                          for c in SAMPLE_CLASSES[:k]},
            "confusion": d["confusion"]}


def _sample_f(seq: Path, checkpoint: Path) -> dict[str, dict]:
    """Sample F of a checkpoint on the labelled frames ("samples") and the propagated ones."""
    from pipeline.config import PipelineConfig
    from pipeline.model import load_checkpoint
    from research.experiments.data import process_scene

    model, meta = load_checkpoint(checkpoint)
    config = PipelineConfig().override({"samples": meta.sample_config.model_dump()})
    scene = process_scene(seq, config)
    k = meta.model_config.num_classes
    scored = scene.gt_class < k  # 7 = ground, 255 = unlabelled (or not carried)
    out = {}
    for name, frames in (("samples", LABELLED), ("propagated", PROPAGATED)):
        keep = scored & np.isin(scene.frame, np.asarray(frames))
        out[name] = _report(model, scene.samples[keep], scene.gt_class[keep], k)
    out["samples"]["of_valid_samples"] = int(np.isin(scene.frame, np.asarray(LABELLED)).sum())
    return out


def score_checkpoint(checkpoint: Path | None = None) -> dict:
    """Point IoU and sample F of a checkpoint (None: the shipped default) on kitti_seq00 frames
    0-2; {"skipped": ...} when the real data is absent."""
    from pipeline.model import DEFAULT_MODEL
    from pipeline.predict import run_predict

    with tempfile.TemporaryDirectory() as tmp:
        seq = kitti_seq00(Path(tmp) / "k00", frames=range(3))
        if seq is None:
            return {"skipped": f"{REAL / 'kitti_seq00'} is absent"}
        summary = run_predict(seq, checkpoint, Path(tmp) / "pred", device="cpu")
        iou = summary["point_iou"]
        result = {
            "model": summary["model"],
            "frames": summary["frames"],
            "point_iou": {"mean_iou": round(100 * iou["mean_iou"], 1),
                          "per_class": {c: None if v is None else round(100 * v, 1) for c, v in iou["iou"].items()}},
            "segments_classified": summary["segments_classified"],
        } | _sample_f(kitti_seq00_propagated(Path(tmp) / "k00_29", range(PROPAGATED.stop), RADIUS),
                      checkpoint or DEFAULT_MODEL)
    return result


def run(out_dir: Path, quick: bool) -> dict:
    result = score_checkpoint()
    if "skipped" in result:
        return result
    result["headline"] = (f"default model on kitti_seq00 frames 0-2: sample mean F {result['samples']['mean_f']:.1f} "
                          f"({result['samples']['samples']} samples), point mIoU {result['point_iou']['mean_iou']:.1f}; "
                          f"frames 3-29 (propagated labels) F {result['propagated']['mean_f']:.1f} "
                          f"({result['propagated']['samples']} samples)")
    out_dir.mkdir(parents=True, exist_ok=True)
    (out_dir / "default_model_detail.json").write_text(json.dumps(result, indent=1))
    return result


def compare(checkpoints: dict[str, Path | None], out_dir: Path) -> dict:
    """Score several checkpoints on the real frames: OUT/default_model_compare.json and a PNG of
    per-class sample F (classes without support left out)."""
    from pipeline.classes import SAMPLE_CLASSES
    from pipeline.plots import plot_f_bars

    scores = {name: score_checkpoint(ck) for name, ck in checkpoints.items()}
    if any("skipped" in s for s in scores.values()):
        return next(s for s in scores.values() if "skipped" in s)
    present = [c for c in SAMPLE_CLASSES if next(iter(scores.values()))["samples"]["per_class"][c]["support"]]
    f = [[np.nan if (v := s["samples"]["per_class"][c]["f"]) is None else v for c in present]
         for s in scores.values()]
    out_dir.mkdir(parents=True, exist_ok=True)
    plot_f_bars(np.array(f, dtype=np.float64), list(scores), present, out_dir / "default_model_compare.png",
                title="Sample F on SemanticKITTI 00, frames 0-2")
    (out_dir / "default_model_compare.json").write_text(json.dumps(scores, indent=1))
    return scores


if __name__ == "__main__":
    import sys

    # python -m bench.bench_default_model OUT_DIR NAME=CKPT ... (CKPT "default": the shipped model)
    pairs = dict(a.split("=", 1) for a in sys.argv[2:])
    res = compare({k: None if v == "default" else Path(v) for k, v in pairs.items()}, Path(sys.argv[1]))
    for name, s in res.items():
        print(name, "frames 0-2 F", s["samples"]["mean_f"], "frames 3-29 F", s["propagated"]["mean_f"],
              "mIoU", s["point_iou"]["mean_iou"])
