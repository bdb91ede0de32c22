"""Constraint pairs: the one place that decides which samples become must-link pairs.

Two kinds, built frame by frame in frame order by `LinkBuilder.add`:

- **track pairs**: each member of a track (a sampled segment with a track id) with the track's
  previous member, scored by the later member's link score. Members without a sample hold no
  pair, so a track links over them.
- **fragment pairs**: the association's fragment links (`association.Links.fragments`: this
  frame's segment, the previous frame's segment) whose two segments are members of two different
  tracks. Each joins the two tracks into a *stitch* (track pair, smaller id first); once an
  operator confirms the stitch, its fragment pairs are must-link pairs too.

tracks.json (`tracks.TrackBuilder`), ingest (`app/jobs/ingest.py`), a track repair's rebuilt pairs
and the experiments' scenes (`research/experiments/data.py`) all take their pairs from here; each
names its members by its own reference (a frame index, a segment row id, a sample index).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class FrameLinks:
    """The pairs one frame adds.

    pairs: (P, 2) int64 references (the track's previous member, this frame's member);
    track: (P,) int64 their track ids; later: (P,) int64 this frame's member as a local segment id.
    fragments: (K, 2) int64 local segment ids (this frame, previous frame) of the fragment pairs;
    fragment_refs: (K, 2) int64 the same as references; stitch: (K, 2) int64 the two tracks,
    smaller id first; share: (K,) float64 the fragment links' shared-point share.
    """

    pairs: np.ndarray
    track: np.ndarray
    later: np.ndarray
    fragments: np.ndarray
    fragment_refs: np.ndarray
    stitch: np.ndarray
    share: np.ndarray


class LinkBuilder:
    """Builds the pairs of a sequence frame by frame (see the module docstring)."""

    def __init__(self) -> None:
        self._last: dict[int, int] = {}  # track id -> reference of its last member
        self._prev_track = np.zeros(0, np.int64)  # previous frame: track id per segment, 0 = not a member
        self._prev_ref = np.zeros(0, np.int64)

    def add(
        self,
        track_id: np.ndarray,
        member: np.ndarray,
        ref: np.ndarray,
        fragments: np.ndarray | None = None,
        share: np.ndarray | None = None,
    ) -> FrameLinks:
        """One frame's pairs. track_id: (S,) track id per segment (<= 0 = none); member: (S,) bool
        segments that hold a sample; ref: (S,) int64 the caller's reference of each segment;
        fragments (E, 2) / share (E,): the frame's fragment links."""
        tid = np.where(np.asarray(member, bool), np.asarray(track_id, np.int64), 0)
        ref = np.asarray(ref, np.int64)
        later = np.flatnonzero(tid > 0)
        keys = tid[later].tolist()
        prev = np.array([self._last.get(k, -1) for k in keys], np.int64)
        has = prev >= 0
        self._last.update(zip(keys, ref[later].tolist(), strict=True))
        frag = np.zeros((0, 2), np.int64) if fragments is None else np.asarray(fragments, np.int64).reshape(-1, 2)
        fshare = np.zeros(0, np.float64) if share is None else np.asarray(share, np.float64)
        inside = (frag[:, 0] < len(tid)) & (frag[:, 1] < len(self._prev_track))
        frag, fshare = frag[inside], fshare[inside]
        ta, tb = tid[frag[:, 0]], self._prev_track[frag[:, 1]]
        kept = (ta > 0) & (tb > 0) & (ta != tb)
        frag = frag[kept]
        links = FrameLinks(
            pairs=np.stack([prev[has], ref[later[has]]], axis=1).reshape(-1, 2),
            track=tid[later[has]],
            later=later[has].astype(np.int64),
            fragments=frag,
            fragment_refs=np.stack([ref[frag[:, 0]], self._prev_ref[frag[:, 1]]], axis=1).reshape(-1, 2),
            stitch=np.sort(np.stack([ta[kept], tb[kept]], axis=1), axis=1).reshape(-1, 2),
            share=fshare[kept],
        )
        self._prev_track, self._prev_ref = tid, ref
        return links

    def gap(self) -> None:
        """A frame left out (an empty scan): no fragment pair reaches across it."""
        self._prev_track, self._prev_ref = np.zeros(0, np.int64), np.zeros(0, np.int64)

    def chain(self, track_id: int, refs: list[int]) -> np.ndarray:
        """(P, 2) int64 the pairs of one track whose members `refs` are given in frame order (a
        track rebuilt after a repair)."""
        one = np.ones(1, np.int64)
        parts = [self.add(track_id * one, one.astype(bool), r * one).pairs for r in refs]
        return np.concatenate(parts) if parts else np.zeros((0, 2), np.int64)


def sample_pairs(track: np.ndarray, frame: np.ndarray) -> np.ndarray:
    """(P, 2) int64 the track pairs of samples given as (M,) track id and (M,) frame arrays (at
    most one sample per track and frame), indices into them, built frame by frame."""
    track, frame = np.asarray(track, np.int64), np.asarray(frame, np.int64)
    builder = LinkBuilder()
    parts = [np.zeros((0, 2), np.int64)]
    for f in np.unique(frame):
        idx = np.flatnonzero(frame == f)
        parts.append(builder.add(track[idx], np.ones(len(idx), bool), idx).pairs)
    return np.concatenate(parts)
