"""tracks.json: tracks, link scores, stitches and pairs from FrameResults."""

from __future__ import annotations

import json

import numpy as np

from pipeline.tracks import TrackBuilder, read_tracks, track_statistics
from tests.pipeline.frame_factory import frame


def _frames():
    nan = float("nan")
    return [
        frame(0, [0, 0, 1, 1, 2, -1], [1, 2, 0], [nan, nan, nan]),
        # track 2 splits: its piece 1 starts track 3, a fragment of track 2's segment
        frame(1, [0, 0, 1, 2, 2, -1], [1, 2, 3], [0.91234, 0.8, nan], fragments=[(2, 1)], share=[0.6]),
        frame(2, [0, 1, -1], [1, 3], [0.7, 0.5]),
    ]


def test_tracks_builder_chains_segments_and_keeps_link_scores():
    b = TrackBuilder()
    for fr in _frames():
        b.add(fr)
    t1, t2, t3 = b.tracks[1], b.tracks[2], b.tracks[3]
    assert t1.frames == [0, 1, 2] and t1.scores == [0.9123, 0.7] and t1.points == [2, 2, 1]
    assert t2.frames == [0, 1] and t3.frames == [1, 2]
    assert b.pairs == [(1, 0, 1, np.float32(0.91234)), (2, 0, 1, np.float32(0.8)), (1, 1, 2, np.float32(0.7)),
                       (3, 1, 2, np.float32(0.5))]
    assert b.stitches == {(2, 3): [1, np.float32(0.6)]}


def test_tracks_json_round_trips(tmp_path):
    b = TrackBuilder()
    for fr in _frames():
        b.add(fr)
    b.write(tmp_path / "tracks.json", True, ["a", "b", "c"])
    tracks, doc = read_tracks(tmp_path / "tracks.json")
    assert [t.id for t in tracks] == [1, 2, 3] and doc["linked"] and doc["frames"] == ["a", "b", "c"]
    assert doc["stitches"] == [{"tracks": [2, 3], "links": 1, "share": 0.6}]
    assert tracks[0].centroids[1] == [1.0, 1.0, 1.0]  # world centroid of frame 1's segment 0
    json.loads((tmp_path / "tracks.json").read_text())


def test_tracks_statistics_count_reviews_for_point_shares():
    # points per track: 5, 3, 3 of 11; the longest first: 5 / 11 < 50 %, 8 / 11 < 90 %
    b = TrackBuilder()
    for fr in _frames():
        b.add(fr)
    st = track_statistics(list(b.tracks.values()), 3)
    assert st["tracks"] == 3 and st["spanning"]["all"] == 1 and st["median_length"] == 2.0
    assert st["reviews_for_share"]["50"] == 2 and st["reviews_for_share"]["90"] == 3
