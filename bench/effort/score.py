"""Scores of an export against the truth: the share of labelled non-ground points with the right
class, the same for ground points, the points left unlabelled; and the error of bulk accepts."""

from __future__ import annotations

from typing import Any

import numpy as np

from bench.effort.service import Api, Export, FrameInfo
from bench.effort.truth import SequenceTruth
from pipeline.classes import UNLABELLED
from pipeline.label_sets import LabelSet


def exported_classes(words: np.ndarray, label_set: LabelSet) -> np.ndarray:
    """(N,) uint8 label-set classes of exported SemanticKITTI words (UNLABELLED for 0)."""
    return label_set.to_index_table()[np.asarray(words, np.uint32) & 0xFFFF]


def is_ground(classes: np.ndarray, label_set: LabelSet) -> np.ndarray:
    """(N,) bool: classes that are one of the set's ground classes (they come after its sample classes)."""
    return (classes >= len(label_set.sample_classes)) & (classes != UNLABELLED)


def score_export(export: Export, truth: SequenceTruth) -> dict[str, Any]:
    """Over the frames that have labels (every input row: NaN, inf and no-return rows included)."""
    ls = truth.label_set
    names = ls.point_class_names
    n = {k: 0 for k in ("ng", "ng_right", "ng_none", "g", "g_right", "g_none")}
    per_class = np.zeros((len(names), 2), np.int64)  # (points, right) per true class
    sources = export.summary.get("sources", [])
    per_source = np.zeros((max(len(sources), 1), 2), np.int64)  # non-ground points (taken, right) per source
    for name, ft in truth.labelled.items():
        if name not in export.labels:
            raise ValueError(f"the export has no labels for frame {name}")
        t, e = ft.per_input_row(), exported_classes(export.labels[name], ls)
        if len(e) != len(t):
            raise ValueError(f"frame {name}: {len(e)} exported labels for {len(t)} points")
        g = is_ground(t, ls)
        ng = ~g & (t != UNLABELLED)
        n["ng"] += int(ng.sum())
        n["ng_right"] += int((ng & (e == t)).sum())
        n["ng_none"] += int((ng & (e == UNLABELLED)).sum())
        n["g"] += int(g.sum())
        n["g_right"] += int((g & (e == t)).sum())
        n["g_none"] += int((g & (e == UNLABELLED)).sum())
        known = t != UNLABELLED
        np.add.at(per_class, (t[known], 0), 1)
        np.add.at(per_class, (t[known], 1), (e[known] == t[known]).astype(np.int64))
        if name in export.sources:
            src = export.sources[name].astype(np.int64)
            np.add.at(per_source, (src[ng], 0), 1)
            np.add.at(per_source, (src[ng], 1), (e[ng] == t[ng]).astype(np.int64))

    def share(a: str, b: str) -> float | None:
        return round(n[a] / n[b], 4) if n[b] else None

    return {
        "non_ground_right": share("ng_right", "ng"), "non_ground_unlabelled": share("ng_none", "ng"),
        "ground_right": share("g_right", "g"), "ground_unlabelled": share("g_none", "g"),
        "non_ground_points": n["ng"], "ground_points": n["g"],
        "non_ground_right_points": n["ng_right"], "ground_right_points": n["g_right"],
        "recall_per_class": {names[c]: round(r / p, 4) for c, (p, r) in enumerate(per_class) if p},
        "non_ground_by_source": {sources[i]: {"share": round(int(a) / n["ng"], 4), "right": round(int(r) / int(a), 4)}
                                 for i, (a, r) in enumerate(per_source) if a and i < len(sources)},
    }


def _all_tracks(admin: Api, sequence_id: int, status: str) -> list[dict[str, Any]]:
    tracks, offset = [], 0
    while True:
        page = admin.get("/tracks", params={"sequence_id": sequence_id, "status": status, "limit": 500, "offset": offset})
        tracks += page["items"]
        offset += 500
        if offset >= page["total"]:
            return tracks


def _track_truth(t: dict[str, Any], frames: list[FrameInfo], payloads: dict[int, np.ndarray],
                 truth: SequenceTruth) -> np.ndarray:
    """The true classes of a track's labelled points in its kept frames."""
    seen = [truth.all[f.name][payloads[f.id] == t["id"]] for f in frames if t["keep_start"] <= f.index <= t["keep_end"]]
    c = np.concatenate(seen) if seen else np.zeros(0, np.uint8)
    return c[c != UNLABELLED]


def bulk_tracks(admin: Api, sequence_id: int) -> dict[int, dict[str, Any]]:
    """The tracks accepted in bulk now, by id (audited, corrected and undone ones are not)."""
    return {int(t["id"]): t for t in _all_tracks(admin, sequence_id, "accepted") if t.get("label_source") == "bulk"}


def bulk_as_accepted(admin: Api, bulk: dict[str, Any], tracks: list[dict[str, Any]], frames: list[FrameInfo],
                     truth: SequenceTruth) -> dict[str, Any]:
    """One bulk accept scored against the truth the moment it was taken, before any audit: its
    `tracks` whose labelled points are mostly of another class than the bulk's."""
    names = truth.label_set.point_class_names
    cls = names.index(bulk["class_name"])
    payloads = {f.id: admin.payload(f.id)["track"] for f in frames}
    wrong = []
    for t in tracks:
        c = _track_truth(t, frames, payloads, truth)
        major = int(np.bincount(c).argmax()) if len(c) else None
        if major != cls:
            wrong.append({"track": int(t["id"]), "points": int(t["n_points"]),
                          "truth": names[major] if major is not None else None})
    return {"bulk": int(bulk["id"]), "class": bulk["class_name"], "tracks": len(tracks),
            "n_tracks": int(bulk["n_tracks"]), "ids": sorted(int(t["id"]) for t in tracks), "wrong": wrong}


def as_accepted_summary(records: list[dict[str, Any]], undone: set[int]) -> dict[str, Any]:
    """The error of bulk accepts as they were taken, over every bulk (undone ones included) and
    over the bulks that stayed."""
    def rate(rs: list[dict[str, Any]]) -> dict[str, Any]:
        n, w = sum(r["tracks"] for r in rs), sum(len(r["wrong"]) for r in rs)
        return {"bulks": len(rs), "tracks": n, "wrong": w, "error": round(w / n, 4) if n else None}
    return {"all": rate(records), "kept": rate([r for r in records if r["bulk"] not in undone]),
            "undone": rate([r for r in records if r["bulk"] in undone]), "bulks": records}


CONFIDENCE_EDGES = (0.5, 0.7, 0.8, 0.9, 0.95, 0.99, 1.01)


def prediction_calibration(admin: Api, sequence_id: int, frames: list[FrameInfo], truth: SequenceTruth) -> dict[str, Any]:
    """How often the pending tracks' predicted classes are their true majority class, per
    confidence bin: tracks, right tracks, points, points of right tracks."""
    payloads = {f.id: admin.payload(f.id)["track"] for f in frames}
    names = truth.label_set.point_class_names
    rows = np.zeros((len(CONFIDENCE_EDGES) - 1, 4), np.int64)
    wrong: dict[str, int] = {}  # "predicted->true" points of wrong predictions at confidence >= 0.9
    for t in _all_tracks(admin, sequence_id, "pending"):
        conf, cls = t.get("predicted_confidence"), t.get("predicted_class")
        c = _track_truth(t, frames, payloads, truth)
        if conf is None or cls is None or not len(c) or conf < CONFIDENCE_EDGES[0]:
            continue
        b = int(np.searchsorted(CONFIDENCE_EDGES, conf, side="right")) - 1
        major = int(np.bincount(c).argmax())
        right = cls in names and major == names.index(cls)
        right = right or (cls == "no_object" and bool(is_ground(np.array([major]), truth.label_set)[0]))
        rows[b] += (1, int(right), len(c), len(c) * int(right))
        if not right and conf >= 0.9:
            key = f"{cls}->{names[major]}"
            wrong[key] = wrong.get(key, 0) + len(c)
    bins = {f"{lo:g}-{hi:g}": {"tracks": int(r[0]), "right": int(r[1]), "points": int(r[2]), "points_right": int(r[3])}
            for lo, hi, r in zip(CONFIDENCE_EDGES[:-1], CONFIDENCE_EDGES[1:], rows, strict=True)}
    return {"bins": bins, "wrong_at_0.9_points": dict(sorted(wrong.items(), key=lambda kv: -kv[1]))}


def bulk_error(admin: Api, sequence_id: int, frames: list[FrameInfo], truth: SequenceTruth) -> dict[str, Any]:
    """The error of the bulk-accepted tracks against the truth: a track is wrong when most of its
    labelled points are of another class (ground included: such a track is no object); shares of
    tracks and of their points, the wrong tracks that are ground, and the share of their labelled
    points whose class differs from the track's."""
    tracks = list(bulk_tracks(admin, sequence_id).values())
    payloads = {f.id: admin.payload(f.id)["track"] for f in frames}
    names, ls = truth.label_set.point_class_names, truth.label_set
    wrong_tracks = wrong_track_points = points = disagree = labelled = ground_tracks = 0
    by_size: dict[str, list[int]] = {"<100": [0, 0], "100-1000": [0, 0], ">1000": [0, 0]}  # (tracks, wrong)
    for t in tracks:
        cls = names.index(t["label"])
        c = _track_truth(t, frames, payloads, truth)
        major = int(np.bincount(c).argmax()) if len(c) else None
        ground = major is None or bool(is_ground(np.array([major]), ls)[0])
        wrong_tracks += major != cls
        ground_tracks += ground
        size = "<100" if t["n_points"] < 100 else "100-1000" if t["n_points"] <= 1000 else ">1000"
        by_size[size][0] += 1
        by_size[size][1] += int(major != cls)
        wrong_track_points += len(c) if major != cls else 0
        points += len(c)
        disagree += int((c != cls).sum())
        labelled += len(c)
    return {"tracks": len(tracks), "points": points,
            "track_error": round(wrong_tracks / len(tracks), 4) if tracks else None,
            "point_weighted_track_error": round(wrong_track_points / points, 4) if points else None,
            "point_disagreement": round(disagree / labelled, 4) if labelled else None,
            "ground_tracks": ground_tracks, "tracks_and_wrong_by_points": by_size}
