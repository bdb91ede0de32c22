"""Online inference: a trained checkpoint over a sequence, one SemanticKITTI `.label` per frame.

`run_predict(seq, checkpoint, out)` runs the perception pipeline (segmentation, samples and
association) with the sample settings the model was trained on, classifies the sample of every
valid segment and writes::

    OUT/labels/NNNNNN.label     uint32 per input point (SemanticKITTI; 0 for rows that are no
                                point, NaN or no return): low 16 bits the semantic id of
                                the class (pipeline.classes.SEMANTICKITTI_WRITE_ID), high 16 bits 0.
                                A valid segment's class goes to all its points, ground points get
                                the ground class (40, road), every other point is unlabelled (0).
    OUT/confidence/NNNNNN.conf  float16 per input point: the softmax probability of the segment's class;
                                0 for ground and unlabelled points (not decided by the classifier).
    OUT/segments/NNNNNN.npz     per classified segment: segment (V,) int32 local id, track (V,)
                                int64 track id, probs (V, K) float16 class probabilities.
    OUT/summary.json            frames, classified segments, points per class, timings, frames/s
                                and, when the sequence has SemanticKITTI labels, point IoU per class.
    OUT/config.yaml             the pipeline config used.

With `smooth_tracks` a segment takes the mean probabilities of its whole track up to and including
this frame (causal: an online system has not seen the later frames), so a track flickers less.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from pipeline.classes import GROUND, UNLABELLED, to_ours, to_semantickitti
from pipeline.config import PipelineConfig
from pipeline.errors import DataError
from pipeline.metrics import point_iou
from pipeline.model import default_model_path, load_checkpoint, predict
from pipeline.processing import FrameResult, SequenceProcessor
from pipeline.progress import QUIET, Progress
from pipeline.sequence import open_sequence

__all__ = ["FramePrediction", "SegmentClassifier", "predict_frame_classes", "run_predict"]


def model_sample_config(config: PipelineConfig, checkpoint_samples: Any, explicit_size: int | None = None) -> PipelineConfig:
    """`config` with the sample settings of the checkpoint (a model only reads canvases like its own).

    An explicit size that differs from the model's is an error naming both.
    """
    if explicit_size is not None and explicit_size != checkpoint_samples.size:
        raise DataError(
            None,
            f"--size {explicit_size} does not match the model, which was trained on "
            f"{checkpoint_samples.size}x{checkpoint_samples.size} samples",
        )
    return config.override({"samples": checkpoint_samples.model_dump()})


class SegmentClassifier:
    """A loaded checkpoint that classifies the samples of FrameResults."""

    def __init__(self, checkpoint: str | Path, device: str = "auto", batch: int = 256) -> None:
        self.path = Path(checkpoint)
        self.model, self.meta = load_checkpoint(checkpoint, device)
        self.batch = batch

    def check_samples(self, samples: np.ndarray, where: str | Path | None = None) -> None:
        net = self.model.config
        want = (net.in_channels, net.size, net.size)
        if samples.ndim != 4 or samples.shape[1:] != want:
            raise DataError(
                where,
                f"samples are {tuple(samples.shape[1:])} but model {self.path} expects {want} "
                "(channels, size, size): render the samples with the model's sample config",
            )

    def probs(self, samples: np.ndarray) -> np.ndarray:
        """(V, K) float32 class probabilities of (V, C, S, S) uint8 canvases."""
        if len(samples) == 0:
            return np.zeros((0, self.model.config.num_classes), np.float32)
        self.check_samples(samples)
        return predict(self.model, samples, self.batch)


@dataclass(frozen=True)
class FramePrediction:
    """Outputs of one frame.

    point_class: (N,) uint8 our class per point (7 = ground, 255 = unlabelled);
    confidence: (N,) float32 probability of the point's class, 0 where no sample was classified;
    segment: (V,) int32 local ids of the classified segments; track: (V,) int64 their track ids;
    probs: (V, K) float32 their class probabilities.
    """

    point_class: np.ndarray
    confidence: np.ndarray
    segment: np.ndarray
    track: np.ndarray
    probs: np.ndarray


def predict_frame_classes(fr: FrameResult, probs: np.ndarray) -> FramePrediction:
    """Spread the (V, K) probabilities of a frame's samples to its points (vectorised)."""
    n_seg = len(fr.segments.n_points)
    seg_class = np.full(n_seg + 1, UNLABELLED, np.uint8)  # last slot: point without a segment
    seg_conf = np.zeros(n_seg + 1, np.float32)
    sample_seg = np.asarray(fr.sample_segment, np.int64)
    if len(sample_seg):
        seg_class[sample_seg] = probs.argmax(axis=1).astype(np.uint8)
        seg_conf[sample_seg] = probs.max(axis=1)
    seg = np.asarray(fr.segment, np.int64)
    idx = np.where(seg >= 0, seg, n_seg)
    point_class = seg_class[idx]
    confidence = seg_conf[idx]
    ground = np.asarray(fr.ground, bool) & (seg < 0)
    point_class[ground] = GROUND
    track = np.asarray(fr.segments.track_id, np.int64)[sample_seg] if len(sample_seg) else np.zeros(0, np.int64)
    return FramePrediction(point_class, confidence, sample_seg.astype(np.int32), track, probs)


class _TrackSmoother:
    """Causal running mean of class probabilities per track id."""

    def __init__(self) -> None:
        self.sums: dict[int, np.ndarray] = {}
        self.counts: dict[int, int] = {}

    def __call__(self, tracks: np.ndarray, probs: np.ndarray) -> np.ndarray:
        out = probs.copy()
        for i, t in enumerate(tracks.tolist()):
            if t <= 0:
                continue
            s = self.sums.get(t)
            s = probs[i].astype(np.float64) if s is None else s + probs[i]
            self.sums[t] = s
            self.counts[t] = self.counts.get(t, 0) + 1
            out[i] = s / self.counts[t]
        return out


def run_predict(
    seq: str | Path,
    checkpoint: str | Path | None,
    out: str | Path,
    config: PipelineConfig | None = None,
    size: int | None = None,
    sensor: str = "auto",
    poses: str = "file",
    device: str = "auto",
    smooth_tracks: bool = False,
    evaluate: bool = True,
    progress: Progress = QUIET,
    log: Callable[[str], None] | None = None,
    fmt: str = "auto",
    batch_frames: int = 8,
    batch_samples: int = 512,
) -> dict[str, Any]:
    """Classify every valid segment of a sequence and write per-frame labels; returns the summary.

    checkpoint: None = the shipped default model (`pipeline.model.default_model_path`).
    size: the sample size asked for on the command line (None = the model's); a mismatch with the
    checkpoint is a DataError. evaluate: compute point IoU when the sequence carries labels.
    The samples of up to `batch_frames` frames (or `batch_samples` samples) go through the CNN in
    one forward pass.
    """
    log = log or (lambda _m: None)
    clf = SegmentClassifier(default_model_path() if checkpoint is None else checkpoint, device)
    config = model_sample_config(config or PipelineConfig(), clf.meta.sample_config, size)
    out = Path(out)
    opened = open_sequence(seq, fmt, sensor if sensor != "auto" else config.sensor.name, poses, progress)
    source, sens, pose_arr = opened.source, opened.sensor, opened.poses
    if pose_arr is None and smooth_tracks:
        log("no poses: tracks are single frames, --smooth-tracks has no effect")
    for sub in ("labels", "confidence", "segments"):
        (out / sub).mkdir(parents=True, exist_ok=True)
    config.dump(out / "config.yaml")

    skipped: list[dict[str, str]] = []

    def on_skip(i: int, err: DataError) -> None:
        skipped.append({"frame": source.frame_name(i), "error": str(err)})
        log(f"skipped frame {source.frame_name(i)}: {err}")

    smoother = _TrackSmoother() if smooth_tracks else None
    proc = SequenceProcessor(config, sens)
    k = clf.model.config.num_classes
    point_counts = np.zeros(256, np.int64)
    segment_counts = np.zeros(k, np.int64)
    preds: list[np.ndarray] = []
    truths: list[np.ndarray] = []
    state = {"frames": 0, "classify": 0.0, "write": 0.0, "eval": evaluate}

    def flush(batch: list[FrameResult]) -> None:
        """Classify the samples of a few frames in one forward (faster than per frame), then write."""
        if not batch:
            return
        tc = time.perf_counter()
        all_probs = clf.probs(np.concatenate([fr.samples for fr in batch]))
        tw = time.perf_counter()
        state["classify"] += tw - tc
        start = 0
        for fr in batch:
            probs = all_probs[start : start + len(fr.samples)]
            start += len(fr.samples)
            if smoother is not None and len(probs):
                probs = smoother(np.asarray(fr.segments.track_id)[fr.sample_segment], probs)
            pred = predict_frame_classes(fr, probs)
            name = fr.name
            labels = to_semantickitti(pred.point_class).astype(np.uint32)
            fr.scan.to_input(labels).tofile(out / "labels" / f"{name}.label")
            fr.scan.to_input(pred.confidence.astype(np.float16)).tofile(out / "confidence" / f"{name}.conf")
            np.savez(
                out / "segments" / f"{name}.npz", segment=pred.segment, track=pred.track, probs=probs.astype(np.float16)
            )
            point_counts[:] += np.bincount(pred.point_class, minlength=256)
            if len(probs):
                segment_counts[:] += np.bincount(probs.argmax(axis=1), minlength=k)
            if state["eval"]:
                if fr.scan.semantic is None:
                    state["eval"] = False
                    preds.clear()
                    truths.clear()
                else:
                    preds.append(pred.point_class)
                    truths.append(to_ours(fr.scan.semantic))
            state["frames"] += 1
        state["write"] += time.perf_counter() - tw
        batch.clear()

    pending: list[FrameResult] = []
    t0 = time.perf_counter()
    for fr in proc.iter_frames(source, progress=progress, samples=True, poses=pose_arr, on_skip=on_skip):
        clf.check_samples(fr.samples, out)
        pending.append(fr)
        if len(pending) >= batch_frames or sum(len(f.samples) for f in pending) >= batch_samples:
            flush(pending)
    flush(pending)
    elapsed = time.perf_counter() - t0
    names = clf.meta.classes
    point_names = {i: n for i, n in enumerate((*names, "ground"))}
    summary: dict[str, Any] = {
        "sequence": str(seq),
        "model": str(clf.path),
        "model_classes": list(names),
        "sample_size": config.samples.size,
        "sample_channels": config.samples.channels,
        "sensor": sens.name,
        "sensor_from": opened.sensor_from,
        "poses": opened.pose_source,
        "smooth_tracks": smooth_tracks,
        "frames": state["frames"],
        "skipped": skipped,
        "segments_classified": {names[i]: int(segment_counts[i]) for i in range(k)},
        "points": {point_names[i]: int(point_counts[i]) for i in point_names} | {"unlabelled": int(point_counts[UNLABELLED])},
        "seconds": round(elapsed, 3),
        "seconds_classify": round(state["classify"], 3),
        "seconds_write": round(state["write"], 3),
        "frames_per_second": round(state["frames"] / elapsed, 2) if elapsed > 0 else None,
        "outputs": {
            "labels": "labels/NNNNNN.label uint32 SemanticKITTI (semantic id, instance 0)",
            "confidence": "confidence/NNNNNN.conf float16 per point, 0 = not classified",
            "segments": "segments/NNNNNN.npz segment, track, probs (float16)",
        },
    }
    if state["eval"] and preds:
        summary["point_iou"] = point_iou(preds, truths).to_dict()
    (out / "summary.json").write_text(json.dumps(summary, indent=2))
    return summary
