"""A class for every point of a sequence, with its source, from what the database holds: the
tracks' decisions and predictions (read once, before streaming) and each frame's artifact.
The rules are `pipeline.propagation`'s; this module feeds them frame by frame and keeps the
decided points of nearby frames at hand for the world-frame search.
"""

from __future__ import annotations

from collections import OrderedDict
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from sqlalchemy import select
from sqlalchemy.orm import Session

from app import crud
from app.artifacts import ArtifactStore
from app.crud.ground_regions import list_regions
from app.models import Frame, Sequence, Track
from pipeline.assist import NO_OBJECT
from pipeline.label_sets import DEFAULT_LABEL_SET, UNLABELLED, LabelSet, preset
from pipeline.propagation import (
    SOURCE,
    SOURCES,
    GroundRegion,
    NearestLabel,
    PointLabels,
    Rules,
    TrackClasses,
    decided_labels,
    region_labels,
    resolve_frame,
    thin,
    to_world,
)

WINDOW = 10  # frames on either side whose decided points a frame's world search reads
CONFIDENCE_BINS = 10


@dataclass(frozen=True)
class ExportOptions:
    """include_ground: write the ground class on ground points no other source labelled;
    reviewed_only: only points of tracks an operator reviewed (no bulk, propagation or
    prediction); rules: how far labels travel (`pipeline.propagation.Rules`)."""

    include_ground: bool = False
    reviewed_only: bool = False
    rules: Rules = field(default_factory=Rules)


@dataclass(frozen=True)
class TrackRow:
    """A track whose class its points take in its kept frames."""

    db_id: int
    key: int
    class_index: int
    source: int
    confidence: float
    keep_start: int
    keep_end: int


@dataclass(frozen=True)
class PointLabelPlan:
    """Everything the per-frame labels need from the database, read before streaming starts."""

    sequence_name: str
    frames: list[tuple[int, str, str, np.ndarray | None]]  # (index, name, artifact, T_world_lidar)
    decided: list[TrackRow]
    predicted: list[TrackRow]
    options: ExportOptions
    no_object: list[TrackRow] = field(default_factory=list)  # discarded, or predicted to be no object
    # the sequence's: its class indices, and the SemanticKITTI ids they are written as
    label_set: LabelSet = field(default_factory=lambda: preset(DEFAULT_LABEL_SET))
    regions: tuple[GroundRegion, ...] = ()  # the operators' ground regions, oldest first

    @property
    def ground_class(self) -> int | None:
        return self.label_set.ground_index


def _pose(pose: list[float] | None) -> np.ndarray | None:
    return None if pose is None else np.asarray(pose, np.float64).reshape(4, 4)


def frame_poses(session: Session, sequence_id: int) -> list[tuple[int, str, str, np.ndarray | None]]:
    """The sequence's frames in order: (index, name, artifact, T_world_lidar or None)."""
    return [(int(i), str(n), str(a), _pose(p)) for i, n, a, p in session.execute(
        select(Frame.index, Frame.name, Frame.artifact, Frame.pose).where(Frame.sequence_id == sequence_id)
        .order_by(Frame.index)).all()]


def stored_regions(session: Session, sequence_id: int, label_set: LabelSet) -> tuple[GroundRegion, ...]:
    """The sequence's live regions, oldest first, with their classes' indices in `label_set`."""
    rows = [(r, label_set.index(r.class_name)) for r in list_regions(session, sequence_id)]
    objects = len(label_set.sample_classes)
    return tuple(GroundRegion(np.asarray(r.polygon, np.float64), c, r.heights, c < objects, r.frame_index,
                              None if r.clip_from_world is None else np.asarray(r.clip_from_world, np.float64).reshape(4, 4))
                 for r, c in rows)


@dataclass(frozen=True)
class RegionCover:
    """What the operators' regions label of a sequence's tracks and samples.

    track_points: per track id, its points in its kept frames that a region labels (what a
    review of the track can no longer change); sample_points (S,): the points of each sample's
    segment; sample_classes (S, C): how many of them regions give each point class."""

    track_points: dict[int, int]
    sample_points: np.ndarray
    sample_classes: np.ndarray


def region_cover(frames: list[tuple[int, str, str, np.ndarray | None]], regions: tuple[GroundRegion, ...],
                 artifacts: ArtifactStore, tracks: list[Any], samples: list[Any], n_classes: int) -> RegionCover:
    """`RegionCover` of `tracks` (rows with id, keep_start, keep_end) and `samples` (rows with
    frame_index, sample_index), the frame's ground estimate as its ground points."""
    cover = RegionCover({}, np.zeros(len(samples), np.int64), np.zeros((len(samples), n_classes), np.int64))
    if not regions:
        return cover
    kept = {int(t.id): (int(t.keep_start), int(t.keep_end)) for t in tracks}
    in_frame: dict[int, list[tuple[int, int]]] = {}
    for j, r in enumerate(samples):
        in_frame.setdefault(int(r.frame_index), []).append((j, int(r.sample_index)))
    for index, _name, art, pose in frames:
        a = artifacts.read_arrays(art, ("points", "track", "ground", "segment", "sample_segment"))
        labels = PointLabels.empty(len(a["track"]))
        region_labels(labels, np.asarray(a["ground"], bool), to_world(a["points"], pose), regions, index)
        ids, n = np.unique(np.asarray(a["track"], np.int64)[labels.labelled], return_counts=True)
        for i, c in zip(ids.tolist(), n.tolist(), strict=True):
            if i in kept and kept[i][0] <= index <= kept[i][1]:
                cover.track_points[i] = cover.track_points.get(i, 0) + c
        if index in in_frame:
            _segment_classes(cover, in_frame[index], labels, np.asarray(a["segment"], np.int64),
                             np.asarray(a["sample_segment"], np.int64))
    return cover


def _segment_classes(cover: RegionCover, rows: list[tuple[int, int]], labels: PointLabels, segment: np.ndarray,
                     sample_segment: np.ndarray) -> None:
    """Fill `cover`'s rows of one frame's samples ((position, sample index) pairs)."""
    c = cover.sample_classes.shape[1]
    m = int(max(segment.max(initial=-1), sample_segment.max(initial=-1))) + 1
    has = segment >= 0
    total = np.bincount(segment[has], minlength=m)
    lab = has & labels.labelled & (labels.class_ < c)
    per = np.bincount(segment[lab] * c + labels.class_[lab], minlength=m * c).reshape(m, c)
    pos, si = (np.array(v, np.int64) for v in zip(*rows, strict=True))
    seg = sample_segment[si]
    cover.sample_points[pos] = total[seg]
    cover.sample_classes[pos] = per[seg]


def point_label_plan(session: Session, sequence: Sequence, options: ExportOptions) -> PointLabelPlan:
    """Read the frames and the tracks whose classes the points take (see `ExportOptions`): the
    accepted tracks' decisions, and the pending tracks' predictions. The points of a track that
    is no object (discarded by an operator, or predicted `no_object`) are treated as ground: a
    decided point reaches them only within the ground radius, and they take the ground class
    when it is asked for."""
    frames = frame_poses(session, sequence.id)
    label_set = crud.label_set_of(sequence)
    index = {name: i for i, name in enumerate(label_set.point_class_names)}
    ground = label_set.ground_index
    rows = session.execute(
        select(Track.id, Track.key, Track.status, Track.label, Track.label_source, Track.predicted_class,
               Track.predicted_confidence, Track.keep_start, Track.keep_end)
        .where(Track.sequence_id == sequence.id, Track.status != "merged")).all()
    decided, predicted, no_object = [], [], []
    for r in rows:
        if r.status == "accepted" and r.label is not None:
            if options.reviewed_only and r.label_source == "bulk":
                continue
            source = SOURCE["bulk"] if r.label_source == "bulk" else SOURCE["reviewed"]
            conf = float(r.predicted_confidence or 1.0) if source == SOURCE["bulk"] else 1.0
            decided.append(TrackRow(int(r.id), int(r.key), index[r.label], source, conf, int(r.keep_start), int(r.keep_end)))
        elif r.status == "discarded" or r.predicted_class == NO_OBJECT:
            no_object.append(TrackRow(int(r.id), int(r.key), UNLABELLED if ground is None else ground, SOURCE["ground"],
                                      1.0, int(r.keep_start), int(r.keep_end)))
        elif r.status == "pending" and r.predicted_class is not None and not options.reviewed_only:
            predicted.append(TrackRow(int(r.id), int(r.key), index[r.predicted_class], SOURCE["predicted"],
                                      float(r.predicted_confidence or 0.0), int(r.keep_start), int(r.keep_end)))
    regions = stored_regions(session, sequence.id, label_set)
    return PointLabelPlan(sequence.name, frames, decided, predicted, options, no_object, label_set, regions)


def _in_frame(rows: list[TrackRow], index: int) -> TrackClasses:
    return TrackClasses.of([(t.db_id, t.class_index, t.source, t.confidence) for t in rows
                            if t.keep_start <= index <= t.keep_end])


@dataclass(frozen=True)
class FrameLabels:
    """One frame's labels: `labels` per point of the artifact, `input_rows` (None = every input row
    is a point), the points' `track` ids, and which points took their own track's class."""

    index: int
    name: str
    labels: PointLabels
    input_rows: np.ndarray | None
    track: np.ndarray
    from_track: np.ndarray
    ground: np.ndarray


class _DecidedClouds:
    """The thinned decided points (world frame) of frames near the one being labelled, read once
    each and dropped once no later frame's window reaches them."""

    def __init__(self, plan: PointLabelPlan, artifacts: ArtifactStore) -> None:
        self.plan, self.artifacts = plan, artifacts
        self.cache: OrderedDict[int, tuple[np.ndarray, PointLabels]] = OrderedDict()

    def _cloud(self, pos: int) -> tuple[np.ndarray, PointLabels]:
        if pos not in self.cache:
            index, _name, art, pose = self.plan.frames[pos]
            a = self.artifacts.read_arrays(art, ("points", "track"))
            labels = decided_labels(a["track"], _in_frame(self.plan.decided, index))
            self.cache[pos] = thin(to_world(a["points"], pose), labels, self.plan.options.rules.voxel)
        return self.cache[pos]

    def field(self, pos: int) -> NearestLabel:
        """The decided points of frames pos - WINDOW .. pos + WINDOW."""
        lo, hi = max(0, pos - WINDOW), min(len(self.plan.frames), pos + WINDOW + 1)
        for old in [p for p in self.cache if p < lo]:
            del self.cache[old]
        clouds = [self._cloud(p) for p in range(lo, hi)]
        points = np.concatenate([c[0] for c in clouds])
        labels = PointLabels(*(np.concatenate([getattr(c[1], f) for c in clouds]) for f in ("class_", "source", "confidence")))
        return NearestLabel(points, labels)


def iter_frame_labels(plan: PointLabelPlan, artifacts: ArtifactStore) -> Iterator[FrameLabels]:
    """Each frame's labels in frame order (`pipeline.propagation.resolve_frame`)."""
    opts = plan.options
    clouds = _DecidedClouds(plan, artifacts)
    ground_class = plan.ground_class if opts.include_ground else None
    for pos, (index, name, art, pose) in enumerate(plan.frames):
        a = artifacts.read_arrays(art, ("points", "track", "ground", "input_rows"))
        track = np.asarray(a["track"], np.int64)
        decided, predicted = _in_frame(plan.decided, index), _in_frame(plan.predicted, index)
        ground = np.asarray(a["ground"], bool) | _in_frame(plan.no_object, index).lookup(track)[0]
        if opts.reviewed_only:
            labels = decided_labels(track, decided)
            region_labels(labels, ground, to_world(a["points"], pose), plan.regions, index)
            if ground_class is not None:
                labels.set(~labels.labelled & ground, ground_class, SOURCE["ground"], 1.0)
        else:
            labels = resolve_frame(track, ground, to_world(a["points"], pose), decided, predicted,
                                   clouds.field(pos), opts.rules, ground_class, plan.regions, index)
        own = decided.lookup(track)[0] | (predicted.lookup(track)[0] & (labels.source == SOURCE["predicted"]))
        yield FrameLabels(index, name, labels, a.get("input_rows"), track, own, ground)


class LabelSummary:
    """Counts of the points written: per source and class, confidence histograms per source, and
    why points stayed without a class."""

    def __init__(self) -> None:
        self.by_source_class = np.zeros((len(SOURCES), 256), np.int64)
        self.confidence = np.zeros((len(SOURCES), CONFIDENCE_BINS), np.int64)
        self.no_point = 0
        self.ground_unwritten = 0
        self.frames = 0

    def add(self, fl: FrameLabels) -> None:
        lab = fl.labels
        np.add.at(self.by_source_class, (lab.source.astype(np.int64), lab.class_.astype(np.int64)), 1)
        bins = np.minimum((lab.confidence * CONFIDENCE_BINS).astype(np.int64), CONFIDENCE_BINS - 1)
        np.add.at(self.confidence, (lab.source.astype(np.int64), bins), 1)
        self.ground_unwritten += int((~lab.labelled & fl.ground).sum())
        if fl.input_rows is not None:
            self.no_point += int(len(fl.input_rows) - len(lab.class_))
        self.frames += 1

    def to_dict(self, options: ExportOptions, label_set: LabelSet) -> dict[str, Any]:
        names = dict(enumerate(label_set.point_class_names))
        by_source = {s: int(self.by_source_class[i].sum()) for i, s in enumerate(SOURCES) if s != "none"}
        per_class = {s: {names[c]: int(n) for c, n in enumerate(self.by_source_class[i]) if n and c in names}
                     for i, s in enumerate(SOURCES) if s != "none"}
        hist = {s: self.confidence[i].tolist() for i, s in enumerate(SOURCES) if s != "none" and self.confidence[i].any()}
        return {
            "sources": list(SOURCES),
            "frames": self.frames,
            "points": int(self.by_source_class.sum()) + self.no_point,
            "labelled_by_source": by_source,
            "labelled_by_source_and_class": per_class,
            "confidence_histogram": {"bins": CONFIDENCE_BINS, "per_source": hist},
            "unlabelled": {"ground_not_asked_for": self.ground_unwritten,
                           "points_no_source_reached": int(self.by_source_class[SOURCE["none"]].sum()) - self.ground_unwritten,
                           "input_rows_that_are_no_point": self.no_point},
            "options": {"include_ground": options.include_ground, "reviewed_only": options.reviewed_only,
                        "radius": options.rules.radius, "ground_radius": options.rules.ground_radius,
                        "far_radius": options.rules.far_radius, "region_radius": options.rules.region_radius},
        }
