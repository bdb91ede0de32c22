"""A simulated operator (and reviewer) working through the REST API as a person at the viewer.

It takes the track the queue offers, looks at its points in the kept frames (and only then
learns their true classes, through a `TruthStore`), and decides as a careful person would:

- one class holds at least `pure` of the labelled points: label the track with it (a track of
  ground, or of nothing labelled, is discarded: it is no object);
- else a box around the largest other class's points would move at least `split_gain` points
  to their right class: split them off with that box (world frame, every kept frame) and label
  both parts;
- else label the majority.

Every `bulk_every` edits it looks at the model's predictions: for each class whose bulk accept at
`bulk_confidence` the preview says was right on at least `bulk_precision` of the held-out reviewed
tracks (over at least `bulk_support` of them), it accepts them all in one action; a reviewer then
audits `audit_per_bulk` of them, and the bulk is undone when the audit corrected any. The operator works at a person's pace: it waits for the model in
the loop to finish a run before it takes the next track.

Counting: every REST call that changes labels is an edit; every track inspected in an audit is
an audit; actions = edits + audits.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from bench.effort.ground import Lasso, plan, plan_prism
from bench.effort.score import exported_classes
from bench.effort.service import Api, FrameInfo
from bench.effort.truth import TruthStore
from pipeline.classes import UNLABELLED
from pipeline.label_sets import DEFAULT_LABEL_SET, LabelSet, preset
from pipeline.propagation import GroundRegion

# the service's worker polls every WORKER_POLL_S (bench_effort sets it); the operator waits this
# long without a model run in sight before it takes the next track
WORKER_POLL_S = 0.2
MODEL_SETTLE_S = 0.5


@dataclass(frozen=True)
class Policy:
    pure: float = 0.9
    split_gain: int = 200  # points a split must move to their right class (and 10 % of the track's)
    bulk_every: int = 10
    bulk_confidence: float = 0.95
    bulk_precision: float = 0.98
    bulk_support: int = 5
    audit_per_bulk: int = 5
    wait_for_model: bool = True
    queue: str = "priority"  # the review queue's order (POST /review/next?order=)
    ground_every: int = 3  # reviews between two looks at every frame from above
    ground_per_frame: float = 1.0  # lassos over the ground layer at most, per frame of the sequence
    prisms_per_frame: float = 4.0  # regions with heights at most, per frame of the sequence
    # what a region must put right (net) before the operator has seen what its reviews do, as a
    # share of the seen points that are not ground; afterwards: what a review put right on average
    region_share: float = 0.002


@dataclass
class Counts:
    edits: int = 0
    audits: int = 0
    audit_corrections: int = 0
    reviews: int = 0
    splits: int = 0
    discards: int = 0
    regions: int = 0
    prisms: int = 0  # of the regions, those with a height range
    bulk_accepts: int = 0
    bulk_tracks: int = 0
    bulk_undos: int = 0
    queue_empty: bool = False

    @property
    def actions(self) -> int:
        return self.edits + self.audits


@dataclass(frozen=True)
class Shown:
    """A track on the screen: per frame name its point indices and world coordinates."""

    points: dict[str, np.ndarray]
    world: dict[str, np.ndarray]


@dataclass
class Operator:
    op: Api
    reviewer: Api
    admin: Api
    sequence_id: int
    frames: list[FrameInfo]
    store: TruthStore
    policy: Policy = field(default_factory=Policy)
    label_set: LabelSet = field(default_factory=lambda: preset(DEFAULT_LABEL_SET))
    input_rows: dict[str, np.ndarray | None] = field(default_factory=dict)  # per frame: the scan rows that are points
    counts: Counts = field(default_factory=Counts)
    on_action: Callable[[], None] | None = None  # called after every action (the benchmark's checkpoints)
    on_bulk: Callable[[dict[str, Any]], None] | None = None  # called after each bulk accept, before its audit
    _payloads: dict[int, dict[str, np.ndarray]] = field(default_factory=dict)
    _prisms: list[Lasso] = field(default_factory=list)  # the regions with heights it drew
    _since: tuple[int, int] | None = None  # (actions, seen points right) when its last look from above ended
    _right: int = 0  # seen points right at its latest look

    # ------------------------------------------------------------------ looking
    def _payload(self, frame: FrameInfo) -> dict[str, np.ndarray]:
        if frame.id not in self._payloads:
            self._payloads[frame.id] = self.op.payload(frame.id)
        return self._payloads[frame.id]

    def show(self, track: dict[str, Any]) -> Shown:
        """Draw the track's points in its kept frames (the store learns what was shown)."""
        self.store.forget()
        points, world = {}, {}
        for f in self.frames:
            if not track["keep_start"] <= f.index <= track["keep_end"]:
                continue
            p = self._payload(f)
            idx = np.flatnonzero(p["track"] == track["id"])
            if len(idx):
                self.store.show(f.name, idx, item=int(track["id"]))
                points[f.name] = idx
                T = f.T_world_lidar
                world[f.name] = p["points"][idx].astype(np.float64) @ T[:3, :3].T + T[:3, 3]
        return Shown(points, world)

    def look(self, shown: Shown) -> tuple[np.ndarray, np.ndarray]:
        """The true classes and world coordinates of the shown points (concatenated)."""
        names = list(shown.points)
        if not names:
            return np.zeros(0, np.uint8), np.zeros((0, 3))
        classes = np.concatenate([self.store.read(n, shown.points[n]) for n in names])
        return classes, np.concatenate([shown.world[n] for n in names])

    # ------------------------------------------------------------------ acting
    def _edit(self, path: str, body: dict[str, Any]) -> Any:
        out = self.op.post(path, body)
        self.counts.edits += 1
        if path.endswith("/split"):
            self._payloads.clear()  # the split rewrote its frames
        self._acted()
        return out

    def _acted(self) -> None:
        if self.on_action is not None:
            self.on_action()

    def _is_object(self, cls: int | None) -> bool:
        """Whether `cls` is one of the label set's sample classes (not ground, not unlabelled)."""
        return cls is not None and cls < len(self.label_set.sample_classes)

    def _decide(self, track: dict[str, Any], cls: int) -> None:
        """Label the track with `cls`, or discard it when `cls` is no object class."""
        if not self._is_object(cls):
            self._edit(f"/tracks/{track['id']}/discard", {"version": track["version"]})
            self.counts.discards += 1
        else:
            self._edit(f"/tracks/{track['id']}/label",
                       {"version": track["version"], "label": self.label_set.point_class_names[cls]})

    def review_next(self) -> bool:
        """Review the track the queue offers; False when the queue is empty."""
        if self.policy.wait_for_model:
            self.admin.wait_jobs_idle("assist", settle=MODEL_SETTLE_S)
        track = self.op.post("/review/next", params={"sequence_id": self.sequence_id, "order": self.policy.queue},
                             ok=(200, 204))
        if track is None:
            self.counts.queue_empty = True
            return False
        self.review(track)
        return True

    def review(self, track: dict[str, Any]) -> None:
        """Look at `track` (TrackPublic) and decide it (module docstring)."""
        classes, world = self.look(self.show(track))
        labelled = classes != UNLABELLED
        if not labelled.any():
            self._decide(track, UNLABELLED)
        else:
            counts = np.bincount(classes[labelled], minlength=len(self.label_set.point_classes))
            major = int(counts.argmax())
            box = None if counts[major] >= self.policy.pure * labelled.sum() else self._split_box(classes, world, major)
            if box is None:
                self._decide(track, major)
            else:
                self._split(track, box, major)
        self.counts.reviews += 1

    def _split_box(self, classes: np.ndarray, world: np.ndarray, major: int) -> tuple[np.ndarray, np.ndarray, int] | None:
        """(centre, size, class) of the world box that moves the most points of the largest
        other class to their own track, when the move is worth a split."""
        labelled = classes != UNLABELLED
        counts = np.bincount(classes[labelled], minlength=len(self.label_set.point_classes))
        counts[major] = 0
        other = int(counts.argmax())
        mine = world[classes == other]
        best: tuple[int, np.ndarray, np.ndarray] | None = None
        for trim in (0.0, 2.0, 5.0, 10.0):
            lo, hi = np.percentile(mine, trim, axis=0) - 0.02, np.percentile(mine, 100 - trim, axis=0) + 0.02
            inside = np.all((world >= lo) & (world <= hi), axis=1)
            gain = int((inside & (classes == other)).sum() - (inside & (classes == major)).sum())
            if best is None or gain > best[0]:
                best = (gain, lo, hi)
        assert best is not None
        gain, lo, hi = best
        if gain < max(self.policy.split_gain, 0.1 * labelled.sum()):
            return None
        return (lo + hi) / 2, hi - lo, other

    def _split(self, track: dict[str, Any], box: tuple[np.ndarray, np.ndarray, int], major: int) -> None:
        centre, size, other = box
        region = {"kind": "box", "center": [float(v) for v in centre], "size": [float(max(v, 0.05)) for v in size]}
        res = self._edit(f"/tracks/{track['id']}/split", {"version": track["version"], "region": region})
        self.counts.splits += 1
        self._decide(res["new_track"], other)
        self._decide(res["track"], major)

    # ------------------------------------------------------------------ the ground layer
    def layer(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Show every frame's points from above: their world x, y, z, true class, current class
        and whether `ground` or a `region` labelled them (the ground layer)."""
        export = self.op.export(self.sequence_id, include_ground=True)
        names = export.summary.get("sources", [])
        layer = [names.index(s) for s in ("ground", "region") if s in names]
        self.store.forget()
        world, true, current, ground = [], [], [], []
        for f in self.frames:
            if f.name not in export.labels or f.name not in self.input_rows:
                continue
            rows = self.input_rows[f.name]
            src, words = export.sources[f.name], export.labels[f.name]
            if rows is not None:
                src, words = src[rows], words[rows]
            idx = np.arange(len(src))
            self.store.show(f.name, idx)
            p = self._payload(f)["points"][idx].astype(np.float64)
            T = f.T_world_lidar
            world.append(p @ T[:3, :3].T + T[:3, 3])
            true.append(self.store.read(f.name, idx))
            current.append(exported_classes(words[idx], self.label_set))
            ground.append(np.isin(src[idx], layer))
        if not world:
            return np.zeros((0, 3)), np.zeros(0, np.uint8), np.zeros(0, np.uint8), np.zeros(0, bool)
        return tuple(np.concatenate(a) for a in (world, true, current, ground))  # type: ignore[return-value]

    def _best_region(self) -> tuple[Lasso | None, int]:
        """The best of a lasso over the ground layer (points the export labels as ground or by a
        region) and a prism over every point, each while its budget lasts; and the seen object
        points (`_need` reads them). Notes the seen points right (`_right`)."""
        n, objects = len(self.label_set.point_classes), len(self.label_set.sample_classes)
        pol, frames = self.policy, len(self.frames)
        world, true, current, ground = self.layer()
        self._right = int(((true == current) & (true != UNLABELLED)).sum())
        self.store.forget()
        for p in self._prisms:  # the points its own prisms label are no ground layer
            ground &= ~GroundRegion(p.polygon, p.class_, p.heights).labels(world, None)
        best = []
        if self.counts.regions - self.counts.prisms < pol.ground_per_frame * frames:
            best.append(plan(world[ground, :2], true[ground], current[ground], n))
        if self.counts.prisms < pol.prisms_per_frame * frames:
            best.append(plan_prism(world, true, current, objects, n))
        return max((r for r in best if r is not None), key=lambda r: r.gain, default=None), int((true < objects).sum())

    def _need(self, seen_objects: int) -> int:
        """The points a region must put right (net), at least one: what an action put right on
        average between the end of the operator's previous look from above and the start of this
        one (the reviews: a region is drawn when it is worth more than the next review), or
        `region_share` of the seen object points at its first look."""
        if self._since is None or self.counts.actions == self._since[0]:
            return max(int(self.policy.region_share * seen_objects), 1)
        actions, right = self._since
        return max((self._right - right) // (self.counts.actions - actions), 1)

    def region_pass(self, budget: int | None = None) -> bool:
        """Draw the regions that put the most seen points right (one action each), the best
        first, while one puts more right than a review would (`_need`) and the budgets last
        (`budget`: the actions); False when none did. The bar is set once, as the look starts:
        the regions of this look would raise it, yet what a region competes with is a review."""
        drawn, need = False, None
        while budget is None or self.counts.actions < budget:
            lasso, seen_objects = self._best_region()
            need = self._need(seen_objects) if need is None else need
            if lasso is None or lasso.gain < need:
                break
            body: dict[str, Any] = {"class_name": self.label_set.point_class_names[lasso.class_],
                                    "polygon": [[float(x), float(y)] for x, y in lasso.polygon]}
            if lasso.heights is not None:
                body["z_min"], body["z_max"] = lasso.heights
            self._edit(f"/sequences/{self.sequence_id}/ground-regions", body)
            self.counts.regions += 1
            if lasso.heights is not None:
                self.counts.prisms += 1
                self._prisms.append(lasso)
            drawn = True
        self._since = (self.counts.actions, self._right)
        return drawn

    # ------------------------------------------------------------------ bulk and audit
    def bulk_round(self) -> None:
        """Accept, class by class, the predictions the preview vouches for; audit each bulk."""
        pol = self.policy
        if pol.wait_for_model:
            self.admin.wait_jobs_idle("assist", settle=MODEL_SETTLE_S)
        for name in self.label_set.sample_class_names:
            p = self.op.get(f"/sequences/{self.sequence_id}/bulk-accept/preview",
                            params={"class_name": name, "min_confidence": pol.bulk_confidence})
            precision = p["held_out_precision"]
            if p["tracks"] == 0 or precision is None or precision < pol.bulk_precision or p["held_out_tracks"] < pol.bulk_support:
                continue
            bulk = self._edit(f"/sequences/{self.sequence_id}/bulk-accept",
                              {"class_name": name, "min_confidence": pol.bulk_confidence, "expected_tracks": p["tracks"]})
            self.counts.bulk_accepts += 1
            self.counts.bulk_tracks += int(bulk["n_tracks"])
            if self.on_bulk:
                self.on_bulk(bulk)
            if self.audit(pol.audit_per_bulk, seed=int(bulk["id"])):
                self._edit(f"/bulk-actions/{bulk['id']}/undo", {})  # the audit found a wrong class: not trusted
                self.counts.bulk_undos += 1

    def audit(self, n: int, seed: int) -> int:
        """The reviewer inspects `n` bulk-accepted tracks drawn at random: agrees; corrects the class
        to the one most of the track's points have; or discards a track of ground. Returns the
        corrections."""
        before = self.counts.audit_corrections
        audits = self.reviewer.post("/audits/sample", {"n": n, "sequence_id": self.sequence_id, "seed": seed,
                                                       "source": "bulk"}, ok=(201,))
        for a in audits:
            track = self.reviewer.get(f"/tracks/{a['track_id']}")
            classes, _ = self.look(self.show(track))
            known = classes[classes != UNLABELLED]
            major = int(np.bincount(known).argmax()) if len(known) else None
            names = self.label_set.point_class_names
            if major is None or (self._is_object(major) and names[major] == a["label"]):
                self.reviewer.post(f"/audits/{a['id']}/agree")
            elif not self._is_object(major):
                self.reviewer.post(f"/audits/{a['id']}/discard")
                self.counts.audit_corrections += 1
            else:
                self.reviewer.post(f"/audits/{a['id']}/correct", {"label": names[major]})
                self.counts.audit_corrections += 1
            self.counts.audits += 1
            self._acted()
        return self.counts.audit_corrections - before
