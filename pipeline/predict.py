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
    OUT/summary.json            frames, classified segments, points per class, timings, frames/s,
                                warnings about inputs unlike the model's training data, and point
                                IoU per class and point accuracy over the frames that have
                                SemanticKITTI labels (`frames_scored` says how many; the others
                                are not scored).
    OUT/config.yaml             the pipeline config used.

The sample canvases show intensity as the model was trained to read it (`SampleConfig.intensity`:
by rank among the sensor's own intensities, `pipeline.intensity`, or raw); a sensor without
intensity gives an empty channel, the shipped model's geometry-only input. Inputs that lie
outside the checkpoint's training statistics (`pipeline.input_stats`: no intensity, intensity on
another scale, a canvas channel out of range) are reported through `log` and in the summary's
`warnings`, each naming its channel.

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
from pipeline.frames import FrameResult
from pipeline.input_stats import input_warnings
from pipeline.metrics import point_iou
from pipeline.model import default_model_path, load_checkpoint, predict
from pipeline.processing import SequenceProcessor
from pipeline.progress import QUIET, Progress
from pipeline.sequence import open_sequence

OUTPUTS = {  # summary.json says what the files are
    "labels": "labels/NNNNNN.label uint32 SemanticKITTI (semantic id, instance 0)",
    "confidence": "confidence/NNNNNN.conf float16 per point, 0 = not classified",
    "segments": "segments/NNNNNN.npz segment, track, probs (float16)",
}

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


class _InputCheck:
    """Compares the first `enough` canvases of a sequence (all of them when it has fewer) with
    the checkpoint's training statistics, once; `warnings` then holds what lies outside."""

    def __init__(self, clf: SegmentClassifier, quantiles: tuple[float, ...], log: Callable[[str], None],
                 enough: int = 256) -> None:
        self.clf, self.quantiles, self.log, self.enough = clf, quantiles, log, enough
        self.parts: list[np.ndarray] = []
        self.warnings: list[str] | None = None

    def add(self, samples: np.ndarray) -> None:
        if self.warnings is None:
            self.parts.append(samples)
            if sum(len(p) for p in self.parts) >= self.enough:
                self.finish()

    def finish(self) -> None:
        if self.warnings is not None:
            return
        samples = np.concatenate(self.parts) if self.parts else np.zeros((0, 4, 1, 1), np.uint8)
        self.warnings = input_warnings(self.clf.meta.input_stats, samples, self.quantiles,
                                       self.clf.meta.sample_config.intensity)
        self.parts.clear()
        for w in self.warnings:
            self.log(w)


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


class _PredictionWriter:
    """Classifies a few frames' samples in one forward (faster than per frame), writes their
    outputs and keeps the counts and labelled frames for the summary."""

    def __init__(self, clf: SegmentClassifier, out: Path, smooth_tracks: bool, evaluate: bool) -> None:
        self.clf, self.out = clf, out
        self.smoother = _TrackSmoother() if smooth_tracks else None
        self.point_counts = np.zeros(256, np.int64)
        self.segment_counts = np.zeros(clf.model.config.num_classes, np.int64)
        self.preds: list[np.ndarray] = []
        self.truths: list[np.ndarray] = []
        self.evaluate = evaluate  # frames with labels are scored, the others only counted
        self.unlabelled_frames = 0
        self.frames, self.classify_s, self.write_s = 0, 0.0, 0.0

    def flush(self, batch: list[FrameResult]) -> None:
        if not batch:
            return
        tc = time.perf_counter()
        all_probs = self.clf.probs(np.concatenate([fr.samples for fr in batch]))
        tw = time.perf_counter()
        self.classify_s += tw - tc
        start = 0
        for fr in batch:
            probs = all_probs[start : start + len(fr.samples)]
            start += len(fr.samples)
            if self.smoother is not None and len(probs):
                probs = self.smoother(np.asarray(fr.segments.track_id)[fr.sample_segment], probs)
            self._write(fr, probs)
        self.write_s += time.perf_counter() - tw
        batch.clear()

    def _write(self, fr: FrameResult, probs: np.ndarray) -> None:
        pred = predict_frame_classes(fr, probs)
        out, name = self.out, fr.name
        fr.scan.to_input(to_semantickitti(pred.point_class).astype(np.uint32)).tofile(out / "labels" / f"{name}.label")
        fr.scan.to_input(pred.confidence.astype(np.float16)).tofile(out / "confidence" / f"{name}.conf")
        np.savez(out / "segments" / f"{name}.npz", segment=pred.segment, track=pred.track, probs=probs.astype(np.float16))
        self.point_counts += np.bincount(pred.point_class, minlength=256)
        if len(probs):
            self.segment_counts += np.bincount(probs.argmax(axis=1), minlength=len(self.segment_counts))
        if self.evaluate and fr.scan.semantic is None:
            self.unlabelled_frames += 1
        elif self.evaluate:
            self.preds.append(pred.point_class)
            self.truths.append(to_ours(fr.scan.semantic))
        self.frames += 1

    def counts(self) -> dict[str, Any]:
        names = self.clf.meta.classes
        point_names = dict(enumerate((*names, "ground")))
        return {
            "segments_classified": {names[i]: int(self.segment_counts[i]) for i in range(len(self.segment_counts))},
            "points": {point_names[i]: int(self.point_counts[i]) for i in point_names}
            | {"unlabelled": int(self.point_counts[UNLABELLED])},
        }


def _summary(seq: str | Path, clf: SegmentClassifier, config: PipelineConfig, opened: Any, smooth_tracks: bool,
             skipped: list[dict[str, str]], writer: _PredictionWriter, check: _InputCheck, elapsed: float) -> dict[str, Any]:
    """summary.json of `run_predict` (module docstring)."""
    summary: dict[str, Any] = {
        "sequence": str(seq),
        "model": str(clf.path),
        "model_classes": list(clf.meta.classes),
        "sample_size": config.samples.size,
        "sample_channels": config.samples.channels,
        "sensor": opened.sensor.name,
        "sensor_from": opened.sensor_from,
        "poses": opened.pose_source,
        "smooth_tracks": smooth_tracks,
        "frames": writer.frames,
        "skipped": skipped,
        **writer.counts(),
        "seconds": round(elapsed, 3),
        "seconds_classify": round(writer.classify_s, 3),
        "seconds_write": round(writer.write_s, 3),
        "frames_per_second": round(writer.frames / elapsed, 2) if elapsed > 0 else None,
        "warnings": check.warnings or [],
        "outputs": OUTPUTS,
    }
    if writer.evaluate:
        summary["frames_scored"] = len(writer.preds)  # the frames that carry labels
    if writer.evaluate and writer.preds:
        summary["point_iou"] = point_iou(writer.preds, writer.truths).to_dict()
        summary |= point_accuracy(writer.preds, writer.truths)
    return summary


def point_accuracy(preds: list[np.ndarray], truths: list[np.ndarray]) -> dict[str, float | None]:
    """Share of the labelled points (truth not unlabelled) whose predicted class is their class,
    and the same over the labelled points that are not ground (the classifier's share)."""
    pred, truth = np.concatenate(preds), np.concatenate(truths)
    labelled = truth != UNLABELLED
    objects = labelled & (truth != GROUND)

    def share(m: np.ndarray) -> float | None:
        return round(float(np.mean(pred[m] == truth[m])), 4) if m.any() else None

    return {"point_accuracy": share(labelled), "object_point_accuracy": share(objects)}


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

    writer = _PredictionWriter(clf, out, smooth_tracks, evaluate)
    check = _InputCheck(clf, sens.intensity_quantiles, log)
    proc = SequenceProcessor(config, sens)
    pending: list[FrameResult] = []
    t0 = time.perf_counter()
    for fr in proc.iter_frames(source, progress=progress, samples=True, poses=pose_arr, on_skip=on_skip):
        clf.check_samples(fr.samples, out)
        check.add(fr.samples)
        pending.append(fr)
        if len(pending) >= batch_frames or sum(len(f.samples) for f in pending) >= batch_samples:
            writer.flush(pending)
    writer.flush(pending)
    check.finish()
    summary = _summary(seq, clf, config, opened, smooth_tracks, skipped, writer, check, time.perf_counter() - t0)
    (out / "summary.json").write_text(json.dumps(summary, indent=2))
    return summary
