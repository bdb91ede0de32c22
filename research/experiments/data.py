"""Data of the simulated experiments: a scene simulated, run through the real perception
pipeline, and reviewed by a simulated careful operator who checks each track against ground truth.

`prepare_scene(cache, seed, frames, size)` returns a `SceneSamples`: every valid segment's
sample with its frame, pipeline track, link score, ground truth (majority object and class of
its points, and that object's share of them), the fraction of the route travelled at its frame
(to split a route into parts A/B/C by distance), and what the operator gives:

- **labels**: a track is accepted when its segments share one ground-truth object; it is
  truncated at the first segment that belongs to another object (or to no object / the ground,
  or whose majority object holds less than `min_purity` of its points); the kept segments get the
  class of the track's object. A track whose first segment is not clean is discarded.
- **verified constraints**: consecutive samples inside the kept part of an accepted track, except
  for tracks labelled unknown (the paper makes no constraints for unknown).
- **automatic constraints**: every link the association made (consecutive samples of a track),
  with its association score, whether right or wrong.
- **stitches**: the association's fragment links (pieces of one object that split, merge or
  reshuffle between frames; `association.Links.fragments`) join two tracks; the operator confirms
  a stitch when both tracks are accepted and show the same object (one yes/no per stitched pair
  of tracks), and the confirmed fragment links become constraints too (none for unknown).

Results are cached as one `.npz` per (seed, frames, start, size, config, source code of the
pipeline and the simulator) under `cache`, so
experiments re-run in seconds and other experiments (fine-tuning) reuse the same scenes.
"""

from __future__ import annotations

import hashlib
import json
import shutil
from dataclasses import asdict, dataclass, field, fields, replace
from pathlib import Path

import numpy as np

from pipeline.classes import GROUND, NUM_SAMPLE_CLASSES, UNLABELLED, to_ours
from pipeline.config import PipelineConfig
from pipeline.progress import QUIET, Progress

CACHE_VERSION = 3  # 3: pairs from pipeline.links, in frame order
UNKNOWN = NUM_SAMPLE_CLASSES - 1


@dataclass(frozen=True)
class SceneSamples:
    """All valid-segment samples of one processed scene (M of them) and the operator's review.

    samples:    (M, C, S, S) uint8 canvases.
    frame:      (M,) int32 frame index.   segment: (M,) int32 local segment id in its frame.
    track:      (M,) int64 pipeline track id (>= 1).
    link_score: (M,) float32 association score of the link to the track's previous sample, NaN at a start.
    gt_class:   (M,) int16 majority class of the segment's points (0..6, 7 ground, 255 unlabelled).
    gt_object:  (M,) int64 majority object (class << 32 | instance).
    gt_purity:  (M,) float32 share of the segment's points on that object.
    progress:   (M,) float32 fraction of the scene's travelled distance at the frame, in [0, 1].
    label:      (M,) int16 the operator's class, -1 = not labelled.
    verified_pairs: (Q, 2) int64 sample indices; auto_pairs: (P, 2) int64; auto_scores: (P,) float32.
    fragment_pairs: (F, 2) int64 sample indices of the fragment links (frame t, frame t-1);
    fragment_scores: (F,) float32 their shared-point share; stitched_pairs: (G, 2) int64 the
    fragment links the operator confirmed (both samples kept, one object, not unknown).
    """

    samples: np.ndarray
    frame: np.ndarray
    segment: np.ndarray
    track: np.ndarray
    link_score: np.ndarray
    gt_class: np.ndarray
    gt_object: np.ndarray
    gt_purity: np.ndarray
    progress: np.ndarray
    label: np.ndarray
    verified_pairs: np.ndarray
    auto_pairs: np.ndarray
    auto_scores: np.ndarray
    fragment_pairs: np.ndarray = field(default_factory=lambda: np.zeros((0, 2), np.int64))
    fragment_scores: np.ndarray = field(default_factory=lambda: np.zeros(0, np.float32))
    stitched_pairs: np.ndarray = field(default_factory=lambda: np.zeros((0, 2), np.int64))

    def __len__(self) -> int:
        return len(self.samples)

    @property
    def labelled(self) -> np.ndarray:
        """(L,) int64 indices of the operator-labelled samples."""
        return np.flatnonzero(self.label >= 0)

    def save(self, path: str | Path) -> None:
        path = Path(path)
        tmp = path.with_name(path.name + ".tmp.npz")
        np.savez(tmp, **asdict(self))
        tmp.replace(path)

    @classmethod
    def load(cls, path: str | Path) -> SceneSamples:
        with np.load(path) as z:
            return cls(**{f.name: z[f.name] for f in fields(cls)})

    def summary(self) -> dict:
        """Counts for reports: samples, labels and pairs per class, link precision."""
        lab = self.label[self.label >= 0]
        per_class = np.bincount(lab, minlength=NUM_SAMPLE_CLASSES)
        gt = self.gt_class[(self.gt_class >= 0) & (self.gt_class < NUM_SAMPLE_CLASSES)]
        right = self.gt_object[self.auto_pairs[:, 0]] == self.gt_object[self.auto_pairs[:, 1]] if len(self.auto_pairs) else []
        return {
            "samples": len(self),
            "frames": int(self.frame.max() + 1) if len(self) else 0,
            "tracks": int(len(np.unique(self.track))),
            "samples_per_gt_class": np.bincount(gt, minlength=NUM_SAMPLE_CLASSES).tolist(),
            "labels": int(len(lab)),
            "labels_per_class": per_class.tolist(),
            "verified_pairs": int(len(self.verified_pairs)),
            "auto_pairs": int(len(self.auto_pairs)),
            "auto_pair_precision": float(np.mean(right)) if len(self.auto_pairs) else None,
            "fragment_pairs": int(len(self.fragment_pairs)),
            "fragment_pair_precision": float(np.mean(self.gt_object[self.fragment_pairs[:, 0]]
                                                     == self.gt_object[self.fragment_pairs[:, 1]]))
            if len(self.fragment_pairs) else None,
            "stitched_pairs": int(len(self.stitched_pairs)),
            "stitched_tracks": int(len(np.unique(self.track[self.stitched_pairs]))) if len(self.stitched_pairs) else 0,
        }


def segment_truth(segment: np.ndarray, n_segments: int, semantic: np.ndarray, instance: np.ndarray) -> tuple[
    np.ndarray, np.ndarray, np.ndarray
]:
    """Majority object of each segment: (class (S,) int16, object key (S,) int64, purity (S,) float32).

    segment: (N,) local segment id per point (-1 = none); semantic/instance: (N,) SemanticKITTI ids.
    Segments without points get class 255, key -1, purity 0.
    """
    cls = to_ours(semantic).astype(np.int64)  # (N,) 0..7 or 255
    key = (cls << 32) | instance.astype(np.int64)  # (N,)
    m = segment >= 0
    seg, key = segment[m].astype(np.int64), key[m]
    out_cls = np.full(n_segments, UNLABELLED, np.int16)
    out_key = np.full(n_segments, -1, np.int64)
    out_pur = np.zeros(n_segments, np.float32)
    if len(seg) == 0:
        return out_cls, out_key, out_pur
    pair, counts = np.unique(np.stack([seg, key], 1), axis=0, return_counts=True)  # sorted by segment
    order = np.lexsort((-counts, pair[:, 0]))  # per segment, largest count first
    pair, counts = pair[order], counts[order]
    first = np.ones(len(pair), bool)
    first[1:] = pair[1:, 0] != pair[:-1, 0]
    totals = np.bincount(seg, minlength=n_segments)
    s = pair[first, 0]
    out_key[s] = pair[first, 1]
    out_cls[s] = (pair[first, 1] >> 32).astype(np.int16)
    out_pur[s] = counts[first] / np.maximum(totals[s], 1)
    return out_cls, out_key, out_pur


def operator_review(
    track: np.ndarray,
    frame: np.ndarray,
    gt_class: np.ndarray,
    gt_object: np.ndarray,
    gt_purity: np.ndarray,
    pairs: np.ndarray,
    min_purity: float = 0.5,
) -> tuple[np.ndarray, np.ndarray]:
    """The careful operator: (label (M,) int16 with -1 = none, verified pairs (Q, 2) int64: the
    track `pairs` (P, 2) whose two samples it kept, none for unknown).

    Per track in frame order: the object of its first sample is the track's object when that
    sample is clean (a sample class, purity >= min_purity); the track is kept up to (not including)
    the first sample that is not clean or belongs to another object.
    """
    m = len(track)
    label = np.full(m, -1, np.int16)
    order = np.lexsort((frame, track))
    t = track[order]
    clean = (gt_class[order] >= 0) & (gt_class[order] < NUM_SAMPLE_CLASSES) & (gt_purity[order] >= min_purity)
    obj = gt_object[order]
    start = np.ones(m, bool)
    start[1:] = t[1:] != t[:-1]
    start_pos = np.maximum.accumulate(np.where(start, np.arange(m), 0))  # (M,) index of the track's first sample
    same = clean & (obj == obj[start_pos]) & clean[start_pos]
    # kept = every sample of the track so far is `same` (a cumulative AND within each track)
    bad = (~same).astype(np.int64)
    cum_bad = np.cumsum(bad)
    base = cum_bad[start_pos] - bad[start_pos]  # bad samples before the track's first one
    kept = cum_bad == base
    label[order[kept]] = gt_class[order[kept]]
    keep_pair = (label[pairs[:, 0]] >= 0) & (label[pairs[:, 1]] >= 0) & (label[pairs[:, 0]] != UNKNOWN)
    return label, pairs[keep_pair]


def confirm_stitches(pairs: np.ndarray, label: np.ndarray, gt_object: np.ndarray) -> np.ndarray:
    """The careful operator's answer to each stitch: (G, 2) the fragment `pairs` (sample indices)
    whose two samples lie in the kept parts of accepted tracks and show one object; none for
    unknown, as for the verified constraints."""
    a, b = pairs[:, 0], pairs[:, 1]
    ok = (label[a] >= 0) & (label[b] >= 0) & (gt_object[a] == gt_object[b]) & (label[a] != UNKNOWN)
    return pairs[ok].astype(np.int64)


def _noisy_track_labels(track: np.ndarray, frame: np.ndarray, gt_class: np.ndarray, gt_object: np.ndarray,
                        gt_purity: np.ndarray, miss_rate: float, mislabel_rate: float,
                        rng: np.random.Generator, min_purity: float = 0.5) -> np.ndarray:
    """(M,) int16 labels of the realistic operator (`realistic_review`), -1 = none."""
    label = np.full(len(track), -1, np.int16)
    order = np.lexsort((frame, track))
    clean = (gt_class >= 0) & (gt_class < NUM_SAMPLE_CLASSES) & (gt_purity >= min_purity)
    starts = np.flatnonzero(np.r_[True, track[order][1:] != track[order][:-1]])
    for lo, hi in zip(starts, np.r_[starts[1:], len(order)], strict=True):
        members = order[lo:hi]
        first = members[0]
        if not clean[first]:
            continue  # discarded, as the careful operator does
        cls = int(gt_class[first])
        if rng.random() < mislabel_rate:  # a wrong class, any other sample class alike
            cls = int(rng.choice([k for k in range(NUM_SAMPLE_CLASSES) if k != cls]))
        n = 1
        for m in members[1:]:
            if not (clean[m] and gt_object[m] == gt_object[first]) and rng.random() >= miss_rate:
                break  # the wrong link seen: truncated here
            n += 1
        label[members[:n]] = cls
    return label


def realistic_review(scene: SceneSamples, miss_rate: float, mislabel_rate: float, seed: int) -> SceneSamples:
    """The scene as an imperfect operator reviews it (assumed rates, not measured ones): at each
    sample where the careful operator truncates a track (another object, an impure segment, the
    ground), this one misses it with probability `miss_rate` and labels on, so the track's later
    samples of other objects get its class and its links become verified constraints; each
    accepted track gets a wrong class (uniform over the other sample classes) with probability
    `mislabel_rate`. Stitches are confirmed as the careful operator does (both tracks kept, one
    object). The ground truth (gt_*) is unchanged, so evaluation still scores the truth."""
    rng = np.random.default_rng(seed)
    label = _noisy_track_labels(scene.track, scene.frame, scene.gt_class, scene.gt_object, scene.gt_purity,
                                miss_rate, mislabel_rate, rng)
    pairs = scene.auto_pairs
    keep = (label[pairs[:, 0]] >= 0) & (label[pairs[:, 1]] >= 0) & (label[pairs[:, 0]] != UNKNOWN)
    # a stitch is confirmed between kept samples of one object whatever classes the tracks were given
    stitched = confirm_stitches(scene.fragment_pairs, np.where(label >= 0, 0, -1).astype(np.int16), scene.gt_object)
    stitched = stitched[(label[stitched[:, 0]] != UNKNOWN) & (label[stitched[:, 0]] == label[stitched[:, 1]])]
    return replace(scene, label=label, verified_pairs=pairs[keep], stitched_pairs=stitched)


# the code that makes a scene's samples (paths from the repository root): all of the pipeline and
# the simulator, so a change anywhere in them (readers, scan, association, samples) makes a new
# cache entry rather than a stale scene
SCENE_SOURCES = ("pipeline", "research/simulation", "research/experiments/data.py")
# pipeline modules that only consume samples (training, inference, their reports): no module that
# makes a scene imports them (tests/research/test_simulation.py checks), so a change to the
# training keeps the cached scenes
SAMPLE_CONSUMERS = frozenset({*(f"pipeline/training/{m}.py" for m in ("__init__", "augment", "data", "loop", "loss", "plots",
                                                                         "sampling", "split")),
                              "pipeline/model.py", "pipeline/finetune.py",
                              "pipeline/anchors.py", "pipeline/predict.py", "pipeline/prediction_files.py", "pipeline/metrics.py",
                              "pipeline/plots.py", "pipeline/input_stats.py"})


def code_fingerprint(sources: tuple[str, ...] = SCENE_SOURCES, skip: frozenset[str] = SAMPLE_CONSUMERS) -> str:
    """sha256 of the paths and bytes of every .py file under `sources` (repository-relative
    files or folders) but those in `skip`; a missing source raises, so a moved module cannot go
    unseen."""
    root = Path(__file__).resolve().parents[2]
    h = hashlib.sha256()
    for name in sources:
        p = root / name
        files = sorted(p.rglob("*.py")) if p.is_dir() else [p]
        if not files or not all(f.is_file() for f in files):
            raise FileNotFoundError(f"cache fingerprint: {p} is missing")
        for f in files:
            if f.relative_to(root).as_posix() in skip:
                continue
            h.update(f.relative_to(root).as_posix().encode())
            h.update(f.read_bytes())
    return h.hexdigest()


def _cache_key(
    seed: int, frames: int, start: int, config: PipelineConfig, crowd: float = 1.0, cyclists: float = 1.0,
    style: str = "a",
    sensor: str = "hdl32e",
) -> str:
    # only the sections that shape the samples: a training or model setting keeps the cached scene
    shaping = config.model_dump(mode="json", exclude={"model", "training"})
    blob = json.dumps([CACHE_VERSION, code_fingerprint(), seed, frames, start, shaping, float(crowd), float(cyclists),
                       style, sensor], sort_keys=True)
    return hashlib.sha256(blob.encode()).hexdigest()[:12]


def _route_progress(poses: np.ndarray) -> np.ndarray:
    """(F,) fraction of the travelled distance at each frame, from the (F, 4, 4) poses."""
    step = np.linalg.norm(np.diff(poses[:, :3, 3], axis=0), axis=1)
    dist = np.concatenate([[0.0], np.cumsum(step)])
    return (dist / max(dist[-1], 1e-9)).astype(np.float32)


def process_scene(seq: str | Path, config: PipelineConfig, progress: Progress = QUIET) -> SceneSamples:
    """Run the perception pipeline over a labelled sequence and let the operator review it."""
    from pipeline.links import LinkBuilder
    from pipeline.processing import SequenceProcessor
    from pipeline.sequence import open_sequence

    opened = open_sequence(seq, sensor=config.sensor.name)
    source, sensor, poses = opened.source, opened.sensor, opened.poses
    assert poses is not None, "simulated sequences carry poses"
    route = _route_progress(np.asarray(poses))
    parts: dict[str, list[np.ndarray]] = {k: [] for k in ("samples", "frame", "segment", "track", "link_score",
                                                           "gt_class", "gt_object", "gt_purity", "auto", "fragments",
                                                           "fragment_scores")}
    proc = SequenceProcessor(config, sensor)
    links = LinkBuilder()  # each sample is named by its index in the scene
    n_done = 0
    for fr in proc.iter_frames(source, progress=progress, samples=True, poses=poses):
        if fr.scan.semantic is None or fr.scan.instance is None:
            raise ValueError(f"{seq}: frame {fr.name} has no labels")
        n_seg = len(fr.segments.n_points)
        cls, key, pur = segment_truth(np.asarray(fr.segment), n_seg, fr.scan.semantic, fr.scan.instance)
        s = np.asarray(fr.sample_segment, np.int64)
        parts["samples"].append(fr.samples)
        parts["frame"].append(np.full(len(s), fr.index, np.int32))
        parts["segment"].append(s.astype(np.int32))
        parts["track"].append(np.asarray(fr.segments.track_id, np.int64)[s])
        parts["link_score"].append(np.asarray(fr.segments.link_score, np.float32)[s])
        parts["gt_class"].append(cls[s])
        parts["gt_object"].append(key[s])
        parts["gt_purity"].append(pur[s])
        ref = np.full(n_seg, -1, np.int64)
        ref[s] = n_done + np.arange(len(s))
        fl = links.add(fr.segments.track_id, ref >= 0, ref, fr.fragments, fr.fragment_share)
        parts["auto"].append(fl.pairs)
        parts["fragments"].append(fl.fragment_refs)
        parts["fragment_scores"].append(fl.share.astype(np.float32))
        n_done += len(s)
    for k, empty in (("auto", np.zeros((0, 2), np.int64)), ("fragments", np.zeros((0, 2), np.int64)),
                     ("fragment_scores", np.zeros(0, np.float32))):
        parts[k].append(empty)
    arr = {k: np.concatenate(v) for k, v in parts.items()}
    auto = arr["auto"].astype(np.int64)
    label, verified = operator_review(arr["track"], arr["frame"], arr["gt_class"], arr["gt_object"], arr["gt_purity"],
                                      auto)
    scores = arr["link_score"][auto[:, 1]]
    scores = np.where(np.isfinite(scores), scores, 0.0).astype(np.float32)
    return SceneSamples(
        samples=arr["samples"], frame=arr["frame"], segment=arr["segment"], track=arr["track"],
        link_score=arr["link_score"], gt_class=arr["gt_class"], gt_object=arr["gt_object"],
        gt_purity=arr["gt_purity"], progress=route[arr["frame"]], label=label, verified_pairs=verified,
        auto_pairs=auto, auto_scores=scores, fragment_pairs=arr["fragments"].astype(np.int64),
        fragment_scores=arr["fragment_scores"],
        stitched_pairs=confirm_stitches(arr["fragments"].astype(np.int64), label, arr["gt_object"]),
    )


def prepare_scene(
    cache: str | Path,
    seed: int,
    frames: int,
    size: int = 64,
    start: int = 0,
    config: PipelineConfig | None = None,
    progress: Progress = QUIET,
    keep_sequence: bool = False,
    crowd: float = 1.0,
    cyclists: float = 1.0,
    style: str = "a",
    sensor: str = "hdl32e",
) -> SceneSamples:
    """Simulate (seed, frames from `start`, `crowd`, `cyclists`, `style`, cast with the preset
    `sensor`), process and review a scene; cached under `cache`."""
    from research.simulation import simulate_sequence

    config = (config or PipelineConfig()).override({"samples": {"size": size}})
    cache = Path(cache)
    cache.mkdir(parents=True, exist_ok=True)
    crowd_tag = (("" if crowd == cyclists == 1.0 else f"_c{crowd:g}x{cyclists:g}") + ("" if style == "a" else f"_{style}")
                 + ("" if sensor == "hdl32e" else f"_{sensor}"))
    key = _cache_key(seed, frames, start, config, crowd, cyclists, style, sensor)
    target = cache / f"scene_s{seed}_f{frames}_o{start}{crowd_tag}_S{size}_{key}.npz"
    if target.exists():
        return SceneSamples.load(target)
    seq = cache / f"seq_s{seed}_f{frames}_o{start}{crowd_tag}"
    simulate_sequence(seq, frames=frames, seed=seed, start=start, progress=progress, crowd=crowd,
                      cyclists=cyclists, style=style, sensor=sensor)
    scene = process_scene(seq, config, progress)
    scene.save(target)
    if not keep_sequence:
        shutil.rmtree(seq, ignore_errors=True)
    return scene


def concat_scenes(scenes: list[SceneSamples]) -> SceneSamples:
    """One scene of several (routes cast with other sensors, say): samples appended in order,
    pair indices shifted with them, frames and tracks renumbered so that no two scenes share one."""
    if len(scenes) == 1:
        return scenes[0]
    index_off = np.cumsum([0] + [len(s) for s in scenes[:-1]])
    shift = {name: index_off for name in ("verified_pairs", "auto_pairs", "fragment_pairs", "stitched_pairs")}
    shift["frame"] = np.cumsum([0] + [int(s.frame.max()) + 1 if len(s) else 0 for s in scenes[:-1]])
    shift["track"] = np.cumsum([0] + [int(s.track.max()) if len(s) else 0 for s in scenes[:-1]])
    out = {}
    for f in fields(SceneSamples):
        parts = [getattr(s, f.name) for s in scenes]
        if f.name in shift:
            parts = [p + o for p, o in zip(parts, shift[f.name], strict=True)]
        out[f.name] = np.concatenate(parts).astype(getattr(scenes[0], f.name).dtype, copy=False)
    return SceneSamples(**out)


def route_part(progress: np.ndarray, bounds: tuple[float, ...] = (0.3, 0.6)) -> np.ndarray:
    """(M,) part index per sample: 0 = A (< 30 % of the route), 1 = B (30-60 %), 2 = C (>= 60 %)."""
    return np.searchsorted(np.asarray(bounds), progress, side="right").astype(np.int64)


def ground_truth_label(scene: SceneSamples) -> np.ndarray:
    """(M,) ground-truth sample class for evaluation on all samples: the majority class, -1 for
    ground / unlabelled majorities."""
    g = scene.gt_class.astype(np.int64)
    return np.where((g >= 0) & (g < NUM_SAMPLE_CLASSES) & (g != GROUND), g, -1)


def evaluation_set(scene: SceneSamples) -> tuple[np.ndarray, np.ndarray]:
    """(indices (E,) int64, classes (E,) int64) of every sample of a scene whose majority is a
    sample class: a test scene is scored on all of them, impure ones by their majority class, not
    on the operator's labels (which leave out impure samples and the rest of a truncated track)."""
    truth = ground_truth_label(scene)
    idx = np.flatnonzero(truth >= 0).astype(np.int64)
    return idx, truth[idx]


@dataclass(frozen=True)
class Split:
    """A scene's labelled samples split by ground-truth object (indices into the scene)."""

    train_labelled: np.ndarray  # (L_t,) labelled samples of training-side objects
    val_labelled: np.ndarray  # (L_v,) labelled samples of validation-side objects
    val_objects: np.ndarray  # ground-truth object keys on the validation side
    val_tracks: np.ndarray  # pipeline tracks that hold validation labels
    min_labelled: np.ndarray  # the few labels (`per_class` per class, a subset of train_labelled)


def split_by_object(
    scene: SceneSamples, val_fraction: float, seed: int, per_class: int, label_seed: int | None = None
) -> Split:
    """Split the operator's labels by ground-truth object (`pipeline.training.split_by_group`):
    an object seen in several tracks (split, merged, broken) has all of its labelled samples on
    one side, so validation never scores a view of an object trained on. Then `per_class` random
    training labels per class (drawn from `label_seed` when set, else from the split's stream)."""
    from pipeline.training import split_by_group

    rng = np.random.default_rng(seed)
    lab = scene.labelled
    # stratified by the objects' true classes: an object of several tracks, one of them given a
    # wrong class by a realistic operator, would otherwise count as several classes and go to
    # validation (at 5 % mislabelled tracks, 74 % of the labels did); for the careful operator the
    # labels are the true classes, so its split is unchanged
    tr, va = split_by_group(scene.gt_class[lab], scene.gt_object[lab], val_fraction, rng)
    train_l, val_l = lab[tr], lab[va]
    if label_seed is not None:  # another draw of the few labels; same split and evaluation sets
        rng = np.random.default_rng([seed, label_seed])
    mins = []
    for k in range(NUM_SAMPLE_CLASSES):
        idx = train_l[scene.label[train_l] == k]
        mins.append(rng.choice(idx, size=min(per_class, len(idx)), replace=False))
    return Split(train_l, val_l, np.unique(scene.gt_object[val_l]), np.unique(scene.track[val_l]),
                 np.sort(np.concatenate(mins)).astype(np.int64))


def training_side(scene: SceneSamples, split: Split, pairs: np.ndarray) -> np.ndarray:
    """(P,) bool: pairs that touch neither a validation object nor a validation track, so no
    constraint (right or wrong) carries a validation object into training."""
    if len(pairs) == 0:
        return np.zeros(0, bool)
    val = np.isin(scene.gt_object[pairs], split.val_objects) | np.isin(scene.track[pairs], split.val_tracks)
    return ~val.any(axis=1)
