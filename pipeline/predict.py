"""Online inference, the algorithm: a trained checkpoint classifies the samples of FrameResults.

`SegmentClassifier` loads a checkpoint and gives class probabilities of canvases;
`predict_frame_classes` spreads a frame's sample probabilities to its points; `TrackSmoother`
averages them causally along tracks; `InputCheck` compares the canvases with the checkpoint's
training statistics (`pipeline.input_stats`: no intensity, intensity on another scale, a canvas
channel out of range). `pipeline.pipeline.run_predict` joins them to a sequence and
`pipeline.prediction_files` writes the outputs.

The sample canvases show intensity as the model was trained to read it (`SampleConfig.intensity`:
by rank among the sensor's own intensities, `pipeline.intensity`, or raw); a sensor without
intensity gives an empty channel, the shipped model's geometry-only input.

With track smoothing a segment takes the mean probabilities of its whole track up to and including
this frame (causal: an online system has not seen the later frames), so a track flickers less.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from pipeline.classes import GROUND, NUM_SAMPLE_CLASSES, UNLABELLED
from pipeline.config import PipelineConfig
from pipeline.errors import DataError
from pipeline.frames import FrameResult
from pipeline.input_stats import input_warnings
from pipeline.model import load_checkpoint, predict

__all__ = ["FramePrediction", "InputCheck", "SegmentClassifier", "TrackSmoother", "model_sample_config",
           "point_accuracy", "predict_frame_classes"]


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

    point_class: (N,) uint8 class index per point in the label set (ground: its ground class,
        255 = unlabelled);
    confidence: (N,) float32 probability of the point's class, 0 where no sample was classified;
    segment: (V,) int32 local ids of the classified segments; track: (V,) int64 their track ids;
    probs: (V, K) float32 their class probabilities.
    """

    point_class: np.ndarray
    confidence: np.ndarray
    segment: np.ndarray
    track: np.ndarray
    probs: np.ndarray


def predict_frame_classes(fr: FrameResult, probs: np.ndarray, ground_class: int = GROUND) -> FramePrediction:
    """Spread the (V, K) probabilities of a frame's samples to its points (vectorised); ground
    points take `ground_class` (the label set's `ground_index`; the default set's ground)."""
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
    point_class[ground] = ground_class
    track = np.asarray(fr.segments.track_id, np.int64)[sample_seg] if len(sample_seg) else np.zeros(0, np.int64)
    return FramePrediction(point_class, confidence, sample_seg.astype(np.int32), track, probs)


class InputCheck:
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


class TrackSmoother:
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


def point_accuracy(preds: list[np.ndarray], truths: list[np.ndarray],
                   num_sample_classes: int = NUM_SAMPLE_CLASSES) -> dict[str, float | None]:
    """Share of the labelled points (truth not unlabelled) whose predicted class is their class,
    and the same over the labelled points that are not ground (the classifier's share): the
    label set's first `num_sample_classes` classes (default: the default set's)."""
    pred, truth = np.concatenate(preds), np.concatenate(truths)
    labelled = truth != UNLABELLED
    objects = labelled & (truth < num_sample_classes)

    def share(m: np.ndarray) -> float | None:
        return round(float(np.mean(pred[m] == truth[m])), 4) if m.any() else None

    return {"point_accuracy": share(labelled), "object_point_accuracy": share(objects)}
