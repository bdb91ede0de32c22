"""The shipped default model (pipeline/models/default.pt, trained on the simulated campus only)
on real scans: SemanticKITTI sequence 00 (HDL-64E), frames 0-9 (the labelled frames) and 10-29
(labels carried from frames 0-9 through the poses), and on inputs of other sensors.

    python -m bench.run_all --only default_model

1. `tracklabel predict` with no --model (the default model): point IoU per class and point
   accuracy against the labels of frames 0-9 (segmentation errors and unclassified points count
   against it).
2. Sample level, as the experiments score models: every valid segment whose points are mostly
   one of the model's classes (`research.experiments.data.process_scene`: the majority class of
   its points), classified by the model: per-class F and mean F, on frames 0-9 ("samples") and
   on frames 10-29 ("propagated"). The propagated labels (`bench.real_data.propagated_labels`)
   cover the static surfaces frames 0-9 saw, from the viewpoints of 20 later frames: more views of
   the same street, a development check, not an independent test. Carried from frame 0 to frames
   1 and 2 they agree with the real labels on 96-98 % of the non-ground points.
3. Intensity (`robustness`): point accuracy on frames 0-9 with the intensity as recorded, set to
   0 (a sensor without intensity) and scaled by 0.01 (another sensor's scale), and the share of
   the classified points the most common class takes on an Ouster OS-1-128 capture (3 scans) and
   on the nuScenes sweep written as an xyz-only PCD, with the warnings predict gives.
Skipped when ../shared/data/real is absent.
"""

from __future__ import annotations

import json
import tempfile
from pathlib import Path

import numpy as np

from bench.real_data import LABELLED_00, REAL, kitti_seq00, kitti_seq00_propagated

LABELLED = LABELLED_00
PROPAGATED = range(10, 30)
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
    """Point IoU and accuracy, sample F and intensity robustness of a checkpoint (None: the
    shipped default) on kitti_seq00 frames 0-9 (and others); {"skipped": ...} when the real data
    is absent."""
    from pipeline.model import DEFAULT_MODEL
    from pipeline.pipeline import PredictOptions, run_predict

    with tempfile.TemporaryDirectory() as tmp:
        seq = kitti_seq00(Path(tmp) / "k00", frames=LABELLED)
        if seq is None:
            return {"skipped": f"{REAL / 'kitti_seq00'} is absent"}
        summary = run_predict(seq, checkpoint, Path(tmp) / "pred", PredictOptions(device="cpu"))
        iou = summary["point_iou"]
        result = {
            "model": summary["model"],
            "frames": summary["frames"],
            "point_iou": {"mean_iou": round(100 * iou["mean_iou"], 1),
                          "per_class": {c: None if v is None else round(100 * v, 1) for c, v in iou["iou"].items()}},
            "point_accuracy": summary["point_accuracy"],
            "object_point_accuracy": summary["object_point_accuracy"],
            "segments_classified": summary["segments_classified"],
        } | _sample_f(kitti_seq00_propagated(Path(tmp) / "k00_29", range(PROPAGATED.stop), RADIUS),
                      checkpoint or DEFAULT_MODEL)
        result["intensity"] = robustness(checkpoint, Path(tmp), summary)
    return result


def _rescaled(dest: Path, factor: float) -> Path:
    """kitti_seq00 frames 0-9 with every intensity multiplied by `factor` (written under dest)."""
    from pipeline.io.semantickitti import read_bin

    seq = kitti_seq00(dest, frames=LABELLED)
    assert seq is not None
    for f in sorted((seq / "velodyne").iterdir()):
        raw = read_bin(f)
        f.unlink()
        raw[:, 3] *= factor
        raw.tofile(f)
    return seq


def _class_share(summary: dict) -> dict:
    """The most common class's share of the classified points (ground and unlabelled left out)."""
    points = {k: v for k, v in summary["points"].items() if k not in ("ground", "unlabelled")}
    total = sum(points.values())
    top = max(points, key=points.get) if total else None
    return {"classified_points": total, "top_class": top,
            "top_share": round(points[top] / total, 3) if total else None, "warnings": summary["warnings"]}


def _xyz_pcd(dest: Path) -> Path:
    """The nuScenes sweep's x, y, z (no intensity, no ring) as dest/0.pcd."""
    from pypcd4 import Encoding, PointCloud

    raw = np.fromfile(next((REAL / "nuscenes_hdl32e").glob("*.pcd.bin")), np.float32).reshape(-1, 5)
    dest.mkdir(parents=True, exist_ok=True)
    PointCloud.from_xyz_points(np.ascontiguousarray(raw[:, :3])).save(dest / "0.pcd", encoding=Encoding.BINARY)
    return dest


def robustness(checkpoint: Path | None, tmp: Path, as_recorded: dict) -> dict:
    """Point accuracy on frames 0-9 with intensity as recorded, zeroed and scaled by 0.01, and the
    class shares on other sensors' inputs (module docstring, 3)."""
    from pipeline.pipeline import PredictOptions, run_predict

    out: dict = {"as_recorded": {k: as_recorded[k] for k in ("point_accuracy", "object_point_accuracy", "warnings")}}
    for name, factor in (("zeroed", 0.0), ("scaled_0.01", 0.01)):
        s = run_predict(_rescaled(tmp / name, factor), checkpoint, tmp / f"pred_{name}", PredictOptions(device="cpu"))
        out[name] = {k: s[k] for k in ("point_accuracy", "object_point_accuracy", "warnings")}
        base = as_recorded["object_point_accuracy"]
        out[name]["object_accuracy_kept"] = round(s["object_point_accuracy"] / base, 3) if base else None
    ouster = REAL / "ouster" / "OS-1-128_v2.3.0_1024x10_lb_n3.pcap"
    try:
        out["ouster_os1_128"] = _class_share(run_predict(ouster, checkpoint, tmp / "pred_ouster", PredictOptions(device="cpu")))
    except Exception as exc:  # noqa: BLE001 - ouster-sdk is an optional extra
        out["ouster_os1_128"] = {"skipped": str(exc)}
    out["nuscenes_xyz_pcd"] = _class_share(run_predict(_xyz_pcd(tmp / "xyz"), checkpoint, tmp / "pred_xyz", PredictOptions(device="cpu")))
    return out


def run(out_dir: Path, quick: bool) -> dict:
    result = score_checkpoint()
    if "skipped" in result:
        return result
    kept = result["intensity"]["zeroed"]["object_accuracy_kept"]
    result["headline"] = (f"default model on kitti_seq00 frames 0-9: sample mean F {result['samples']['mean_f']:.1f} "
                          f"({result['samples']['samples']} samples), point mIoU {result['point_iou']['mean_iou']:.1f}; "
                          f"frames 10-29 (propagated labels) F {result['propagated']['mean_f']:.1f} "
                          f"({result['propagated']['samples']} samples); intensity zeroed keeps {kept} of the "
                          f"object point accuracy")
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
                title="Sample F on SemanticKITTI 00, frames 0-9")
    (out_dir / "default_model_compare.json").write_text(json.dumps(scores, indent=1))
    return scores


if __name__ == "__main__":
    import sys

    # python -m bench.bench_default_model OUT_DIR NAME=CKPT ... (CKPT "default": the shipped model)
    pairs = dict(a.split("=", 1) for a in sys.argv[2:])
    res = compare({k: None if v == "default" else Path(v) for k, v in pairs.items()}, Path(sys.argv[1]))
    for name, s in res.items():
        print(name, "frames 0-9 F", s["samples"]["mean_f"], "frames 10-29 F", s["propagated"]["mean_f"],
              "mIoU", s["point_iou"]["mean_iou"], "object accuracy", s["object_point_accuracy"],
              "zeroed", s["intensity"]["zeroed"]["object_point_accuracy"])
