"""The files of `tracklabel predict` (`pipeline.pipeline.run_predict`)::

    OUT/labels/NNNNNN.label     uint32 per input point (SemanticKITTI; 0 for rows that are no
                                point, NaN or no return): low 16 bits the semantic id of
                                the class (the id the label set's class writes), high 16 bits 0.
                                A valid segment's class goes to all its points, ground points get
                                the set's first ground class (the default set's: 40, road), every
                                other point is unlabelled (0).
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
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import numpy as np

from pipeline.classes import UNLABELLED
from pipeline.config import PipelineConfig
from pipeline.frames import FrameResult
from pipeline.label_sets import LabelSet
from pipeline.metrics import point_iou
from pipeline.predict import (
    InputCheck,
    SegmentClassifier,
    TrackSmoother,
    point_accuracy,
    predict_frame_classes,
)

OUTPUTS = {  # summary.json says what the files are
    "labels": "labels/NNNNNN.label uint32 SemanticKITTI (semantic id, instance 0)",
    "confidence": "confidence/NNNNNN.conf float16 per point, 0 = not classified",
    "segments": "segments/NNNNNN.npz segment, track, probs (float16)",
}


class PredictionWriter:
    """Classifies a few frames' samples in one forward (faster than per frame), writes their
    outputs and keeps the counts and labelled frames for the summary."""

    def __init__(self, clf: SegmentClassifier, out: Path, smooth_tracks: bool, evaluate: bool,
                 label_set: LabelSet) -> None:
        self.clf, self.out, self.label_set = clf, out, label_set  # the model's set (pipeline.model.check_label_set)
        self.to_index, self.to_semantickitti = label_set.to_index_table(), label_set.to_semantickitti_table()
        ground = label_set.ground_index
        self.ground_class = UNLABELLED if ground is None else ground
        self.smoother = TrackSmoother() if smooth_tracks else None
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
        pred = predict_frame_classes(fr, probs, self.ground_class)
        out, name = self.out, fr.name
        fr.scan.to_input(self.to_semantickitti[pred.point_class].astype(np.uint32)).tofile(out / "labels" / f"{name}.label")
        fr.scan.to_input(pred.confidence.astype(np.float16)).tofile(out / "confidence" / f"{name}.conf")
        np.savez(out / "segments" / f"{name}.npz", segment=pred.segment, track=pred.track, probs=probs.astype(np.float16))
        self.point_counts += np.bincount(pred.point_class, minlength=256)
        if len(probs):
            self.segment_counts += np.bincount(probs.argmax(axis=1), minlength=len(self.segment_counts))
        if self.evaluate and fr.scan.semantic is None:
            self.unlabelled_frames += 1
        elif self.evaluate:
            self.preds.append(pred.point_class)
            self.truths.append(self.to_index[np.asarray(fr.scan.semantic).astype(np.int64) & 0xFFFF])
        self.frames += 1

    def counts(self) -> dict[str, Any]:
        names = self.clf.meta.classes
        point_names = dict(enumerate(self.label_set.point_class_names))
        return {
            "segments_classified": {names[i]: int(self.segment_counts[i]) for i in range(len(self.segment_counts))},
            "points": {point_names[i]: int(self.point_counts[i]) for i in point_names}
            | {"unlabelled": int(self.point_counts[UNLABELLED])},
        }


def prediction_summary(seq: str | Path, clf: SegmentClassifier, config: PipelineConfig, opened: Any, smooth_tracks: bool,
             skipped: list[dict[str, str]], writer: PredictionWriter, check: InputCheck, elapsed: float) -> dict[str, Any]:
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
        point_classes = writer.label_set.point_class_names
        summary["point_iou"] = point_iou(writer.preds, writer.truths, len(point_classes), point_classes).to_dict()
        summary |= point_accuracy(writer.preds, writer.truths, len(writer.label_set.sample_classes))
    return summary
