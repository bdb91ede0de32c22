"""The only module that joins the algorithm to the dataset loaders.

`run_predict` classifies a sequence's segments with a trained checkpoint (`pipeline.predict`)
and writes the files of `pipeline.prediction_files`. `run_process` opens a sequence (`pipeline.sequence.open_sequence`: reader, sensor, width, poses),
runs the SequenceProcessor and writes `OUT/tracks/NNNNNN.label` (one uint32 per input point,
docs/conventions.md), `OUT/tracks.json`, `OUT/summary.json`, `OUT/config.yaml` and, with samples
on, `OUT/samples/NNNNNN.npz`. `evaluate_folder` scores such an output against the sequence's
SemanticKITTI labels.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from pipeline.config import PipelineConfig
from pipeline.errors import DataError
from pipeline.evaluation import FrameTruth, evaluate_frames, evaluate_stitches, object_keys, quality_summary
from pipeline.frames import FrameResult
from pipeline.io import open_reader
from pipeline.label_sets import DEFAULT_LABEL_SET, load_label_set
from pipeline.processing import SequenceProcessor
from pipeline.progress import QUIET, Progress
from pipeline.sequence import Sequence, open_sequence
from pipeline.tracks import TrackBuilder, read_tracks, track_statistics


def _stats(values: list[float]) -> dict[str, float]:
    if not values:
        return {"median": 0.0, "p95": 0.0}
    a = np.asarray(values)
    return {"median": round(float(np.median(a)), 3), "p95": round(float(np.percentile(a, 95)), 3)}


@dataclass
class _Tally:
    """What `run_process` counts over the frames it writes."""

    names: list[str] = field(default_factory=list)
    segments: int = 0
    valid: int = 0
    samples: int = 0
    timings: dict[str, list[float]] = field(default_factory=dict)
    skipped: list[dict[str, str]] = field(default_factory=list)

    def add(self, fr: FrameResult) -> None:
        self.names.append(fr.name)
        self.segments += len(fr.segments)
        self.valid += int(fr.segments.valid.sum())
        self.samples += len(fr.samples)
        for k, v in fr.timings_ms.items():
            self.timings.setdefault(k, []).append(v)


def run_process(
    path: str | Path,
    out: str | Path,
    config: PipelineConfig | None = None,
    sensor: str = "auto",
    poses: str = "file",
    workers: int = 1,
    samples: bool = False,
    progress: Progress = QUIET,
    log: Callable[[str], None] | None = None,
    fmt: str = "auto",
) -> dict:
    """Process a sequence into track labels, tracks.json and summary.json; returns the summary.

    Samples are always rendered (they are part of the run); `samples=True` also writes them.
    """
    config = config or PipelineConfig()
    log = log or (lambda _m: None)
    out = Path(out)
    # 1. open the sequence and the output folder
    seq = open_sequence(path, fmt, sensor if sensor != "auto" else config.sensor.name, poses, progress)
    if seq.poses is None:
        log("no poses (pass --poses icp to estimate them): frames are segmented but not linked into tracks")
    (out / "tracks").mkdir(parents=True, exist_ok=True)
    if samples:
        (out / "samples").mkdir(exist_ok=True)
    config.dump(out / "config.yaml")
    tally = _Tally()

    def on_skip(i: int, err: DataError) -> None:
        tally.skipped.append({"frame": seq.source.frame_name(i), "error": str(err)})
        log(f"skipped frame {seq.source.frame_name(i)}: {err}")

    # 2. process and write every frame, collecting its segments into tracks
    proc = SequenceProcessor(config, seq.sensor)
    builder = TrackBuilder()
    t0 = time.perf_counter()
    for fr in proc.iter_frames(seq.source, progress=progress, workers=workers, samples=True,
                               poses=seq.poses, on_skip=on_skip):
        _write_frame(out, fr, samples)
        builder.add(fr)
        tally.add(fr)
    elapsed = time.perf_counter() - t0
    # 3. the tracks and the summary
    builder.write(out / "tracks.json", proc.linked, tally.names)
    summary = {"sequence": str(path), **_summary(seq, proc, builder, tally, elapsed),
               "workers": workers, "sample_size": config.samples.size, "samples_written": samples}
    (out / "summary.json").write_text(json.dumps(summary, indent=2))
    return summary


def _write_frame(out: Path, fr: FrameResult, samples: bool) -> None:
    """OUT/tracks/NAME.label and, with `samples`, OUT/samples/NAME.npz."""
    fr.scan.to_input(fr.track_labels()).tofile(out / "tracks" / f"{fr.name}.label")
    if samples:
        np.savez_compressed(
            out / "samples" / f"{fr.name}.npz",
            samples=fr.samples,
            segment=fr.sample_segment,
            track_id=fr.segments.track_id[fr.sample_segment],
        )


def _summary(seq: Sequence, proc: SequenceProcessor, builder: TrackBuilder, tally: _Tally, elapsed: float) -> dict:
    """summary.json's counts, track statistics and timings."""
    names, timings, tracks = tally.names, tally.timings, list(builder.tracks.values())
    lengths = np.asarray([len(t.frames) for t in tracks] or [0])
    per_frame = [sum(v) for v in zip(*(timings[k] for k in ("project", "ground", "segment")), strict=True)] \
        if timings else []
    return {
        "format": seq.source.format,
        "sensor": seq.sensor.name,
        "sensor_from": seq.sensor_from,
        "range_image": [seq.sensor.n_rings, seq.sensor.width],
        "poses": seq.pose_source,
        "linked": proc.linked,
        "frames": len(names),
        "skipped": tally.skipped,
        "segments": tally.segments,
        "valid_segments": tally.valid,
        "samples": tally.samples,
        "tracks": len(tracks),
        "tracks_multi_frame": int((lengths > 1).sum()),
        "tracks_spanning_all_frames": int((lengths == len(names)).sum()) if names else 0,
        "constraint_pairs": len(builder.pairs),
        "stitches": len(builder.stitches),
        "mean_track_length": float(lengths.mean()),
        "track_statistics": track_statistics(tracks, len(names)),
        "ms": {k: _stats(v) for k, v in timings.items()},
        "ms_project_ground_segment": _stats(per_frame),
        "seconds": round(elapsed, 3),
        "frames_per_second": round(len(names) / elapsed, 2) if elapsed > 0 else None,
    }


def evaluate_folder(seq: str | Path, out: str | Path, progress: Progress = QUIET) -> dict:
    """Evaluate `tracklabel process` output `out` against the labels of sequence `seq`; frames
    without labels are left out (links are scored between consecutive labelled frames)."""
    out = Path(out)
    tracks_file = out / "tracks.json"
    if not tracks_file.exists():
        raise DataError(tracks_file, "missing: run `tracklabel process` first")
    tracks, doc = read_tracks(tracks_file)
    source = open_reader(seq)
    names = [source.frame_name(i) for i in range(len(source))]
    pos_of_name = {n: i for i, n in enumerate(names)}
    frames: list[FrameTruth] = []
    kept_names = doc["frames"]
    index_of: dict[int, int] = {}
    for name in progress.iterate(kept_names, "evaluate"):
        if name not in pos_of_name:
            raise DataError(out, f"frame {name} of tracks.json is not in {seq}")
        scan = source.frame(pos_of_name[name])
        if scan.semantic is None or scan.instance is None:
            continue
        label_file = out / "tracks" / f"{name}.label"
        track = np.fromfile(label_file, dtype=np.uint32)
        if len(track) != scan.n_input:
            raise DataError(label_file, f"has {len(track)} ids but the scan has {scan.n_input} points")
        if scan.input_rows is not None:
            track = track[scan.input_rows]
        key, inst = object_keys(scan.semantic, scan.instance)
        index_of[pos_of_name[name]] = len(frames)
        frames.append(FrameTruth(track, key, inst, scan.points))
    if not frames:
        raise DataError(seq, "no frame has labels: evaluation needs SemanticKITTI labels")
    links = []
    for t in tracks:
        for a, b in zip(t.frames[:-1], t.frames[1:], strict=True):
            if a in index_of and b in index_of and index_of[b] == index_of[a] + 1:
                links.append((index_of[a], t.id))
    result = evaluate_frames(frames, links)
    result["summary"] = quality_summary(frames, links)
    result["frames"] = len(frames)
    stitches = np.asarray([st["tracks"] for st in doc.get("stitches", [])], np.int64).reshape(-1, 2)
    result["stitches"] = evaluate_stitches(frames, stitches)
    return result


@dataclass(frozen=True)
class PredictOptions:
    """How `run_predict` reads the sequence and runs the model.

    size: the sample size asked for on the command line (None = the model's); a mismatch with the
    checkpoint is a DataError. evaluate: compute point IoU when the sequence carries labels.
    smooth_tracks: average class probabilities along each track (causal). The samples of up to
    `batch_frames` frames (or `batch_samples` samples) go through the CNN in one forward pass.
    label_set: a preset name or a label set file; the checkpoint must have been trained on it.
    """

    size: int | None = None
    sensor: str = "auto"
    poses: str = "file"
    fmt: str = "auto"
    device: str = "auto"
    smooth_tracks: bool = False
    evaluate: bool = True
    batch_frames: int = 8
    batch_samples: int = 512
    label_set: str = DEFAULT_LABEL_SET


def run_predict(
    seq: str | Path,
    checkpoint: str | Path | None,
    out: str | Path,
    options: PredictOptions = PredictOptions(),
    config: PipelineConfig | None = None,
    progress: Progress = QUIET,
    log: Callable[[str], None] | None = None,
) -> dict:
    """Classify every valid segment of a sequence and write per-frame labels (the files of
    `pipeline.prediction_files`); returns the summary. checkpoint: None = the shipped default
    model (`pipeline.model.default_model_path`)."""
    from pipeline.model import check_label_set, default_model_path
    from pipeline.predict import InputCheck, SegmentClassifier, model_sample_config
    from pipeline.prediction_files import PredictionWriter, prediction_summary

    log = log or (lambda _m: None)
    o = options
    # 1. the model, the config its samples need, the sequence and the output folder
    clf = SegmentClassifier(default_model_path() if checkpoint is None else checkpoint, o.device)
    label_set = load_label_set(o.label_set)
    check_label_set(clf.meta, label_set, clf.path)  # predict writes the model's own set
    config = model_sample_config(config or PipelineConfig(), clf.meta.sample_config, o.size)
    out = Path(out)
    opened = open_sequence(seq, o.fmt, o.sensor if o.sensor != "auto" else config.sensor.name, o.poses, progress)
    if opened.poses is None and o.smooth_tracks:
        log("no poses: tracks are single frames, --smooth-tracks has no effect")
    for sub in ("labels", "confidence", "segments"):
        (out / sub).mkdir(parents=True, exist_ok=True)
    config.dump(out / "config.yaml")
    skipped: list[dict[str, str]] = []

    def on_skip(i: int, err: DataError) -> None:
        skipped.append({"frame": opened.source.frame_name(i), "error": str(err)})
        log(f"skipped frame {opened.source.frame_name(i)}: {err}")

    # 2. classify the frames' samples a few frames at a time and write their files
    writer = PredictionWriter(clf, out, o.smooth_tracks, o.evaluate, label_set)
    check = InputCheck(clf, opened.sensor.intensity_quantiles, log)
    pending: list[FrameResult] = []
    t0 = time.perf_counter()
    for fr in SequenceProcessor(config, opened.sensor).iter_frames(
            opened.source, progress=progress, samples=True, poses=opened.poses, on_skip=on_skip):
        clf.check_samples(fr.samples, out)
        check.add(fr.samples)
        pending.append(fr)
        if len(pending) >= o.batch_frames or sum(len(f.samples) for f in pending) >= o.batch_samples:
            writer.flush(pending)
    writer.flush(pending)
    check.finish()
    # 3. the summary
    summary = prediction_summary(seq, clf, config, opened, o.smooth_tracks, skipped, writer, check,
                                 time.perf_counter() - t0)
    (out / "summary.json").write_text(json.dumps(summary, indent=2))
    return summary
