"""Tracks: chains of linked segments, built from FrameResults, and their files.

`tracks.json` layout::

    {"linked": true, "frames": [names...],
     "tracks": [{"id": 7, "frames": [3, 4, 5], "points": [120, 131, 118],
                 "centroids": [[x, y, z], ...] (world frame, or lidar frame when unlinked),
                 "scores": [0.91, 0.88]}],          # one score per link (len(frames) - 1)
     "stitches": [{"tracks": [7, 12], "links": 5, "share": 0.83}]}

Consecutive frames of a track are must-link constraint pairs. A stitch joins two tracks whose
segments are pieces of one object that split, merged or reshuffled between frames (the
association's fragment links: `links` of them, the largest shared-point `share`); once an operator
confirms that both tracks show one object, its fragment links are must-link pairs too. Both come
from `pipeline.links.LinkBuilder`.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from pipeline.frames import FrameResult
from pipeline.links import LinkBuilder


@dataclass
class Track:
    """One track: frame indices (ascending, consecutive), per-frame point counts and centroids
    (mm resolution), and the score of each link (len(frames) - 1, 1e-4 resolution)."""

    id: int
    frames: list[int] = field(default_factory=list)
    points: list[int] = field(default_factory=list)
    centroids: list[list[float]] = field(default_factory=list)
    scores: list[float] = field(default_factory=list)

    def to_dict(self) -> dict:
        return {"id": self.id, "frames": self.frames, "points": self.points, "centroids": self.centroids,
                "scores": self.scores}


class TrackBuilder:
    """Accumulates tracks from FrameResults in frame order."""

    def __init__(self) -> None:
        self.tracks: dict[int, Track] = {}
        self.stitches: dict[tuple[int, int], list[float]] = {}  # (track a, track b), a < b -> [links, share]
        # (track id, frame i, frame i+1, link score) for every link, in frame order
        self.pairs: list[tuple[int, int, int, float]] = []
        self._links = LinkBuilder()

    def add(self, fr: FrameResult) -> None:
        seg = fr.segments
        track_id = np.asarray(seg.track_id, np.int64)
        links = self._links.add(track_id, track_id > 0, np.full(len(track_id), fr.index), fr.fragments,
                                fr.fragment_share)
        for (a, b), sh in zip(links.stitch.tolist(), links.share.tolist(), strict=True):
            st = self.stitches.setdefault((a, b), [0, 0.0])
            st[0] += 1
            st[1] = max(st[1], sh)
        for tid, (fa, fb), k in zip(links.track.tolist(), links.pairs.tolist(), links.later.tolist(), strict=True):
            self.pairs.append((tid, fa, fb, float(seg.link_score[k])))
        kept = np.flatnonzero(seg.track_id > 0)
        # rounded here, once per frame, as tracks.json stores them
        centroids = np.round(np.asarray(seg.centroid_world, np.float64)[kept], 3).tolist()
        scores = np.round(np.asarray(seg.link_score, np.float64)[kept], 4).tolist()
        for tid, n, centroid, score in zip(seg.track_id[kept].tolist(), seg.n_points[kept].tolist(), centroids,
                                           scores, strict=True):
            tr = self.tracks.get(tid)
            if tr is None:
                tr = self.tracks[tid] = Track(tid)
            elif score == score:  # NaN: the track starts here
                tr.scores.append(score)
            tr.frames.append(fr.index)
            tr.points.append(n)
            tr.centroids.append(centroid)

    def write(self, path: str | Path, linked: bool, frame_names: list[str]) -> None:
        data = {
            "linked": linked,
            "frames": frame_names,
            "tracks": [t.to_dict() for t in sorted(self.tracks.values(), key=lambda t: t.id)],
            "stitches": [{"tracks": [a, b], "links": int(n), "share": round(float(sh), 3)}
                         for (a, b), (n, sh) in sorted(self.stitches.items())],
        }
        Path(path).write_text(json.dumps(data, separators=(",", ":")))


def track_statistics(tracks: list[Track], frames: int) -> dict:
    """How long tracks are and how much review they need: tracks spanning >= 10 / 30 / all of
    `frames` frames, and the reviews (one per track, longest tracks first, then the larger) that
    cover 50 / 90 % of the tracked points."""
    lengths = np.asarray([len(t.frames) for t in tracks], np.int64)
    points = np.asarray([sum(t.points) for t in tracks], np.float64)
    order = np.lexsort((-points, -lengths))
    covered = np.cumsum(points[order]) / max(points.sum(), 1.0)

    def reviews(share: float) -> int:
        return int(np.searchsorted(covered, share - 1e-9) + 1) if len(covered) else 0

    return {
        "tracks": len(tracks),
        "median_length": float(np.median(lengths)) if len(lengths) else 0.0,
        "spanning": {"10": int((lengths >= 10).sum()), "30": int((lengths >= 30).sum()),
                     "all": int((lengths >= frames).sum()) if frames else 0},
        "reviews_for_share": {"50": reviews(0.5), "90": reviews(0.9)},
    }


def read_tracks(path: str | Path) -> tuple[list[Track], dict]:
    """Tracks and the raw document of a `tracks.json`."""
    data = json.loads(Path(path).read_text())
    tracks = [
        Track(t["id"], list(t["frames"]), list(t["points"]), list(t["centroids"]), list(t["scores"]))
        for t in data["tracks"]
    ]
    return tracks, data
