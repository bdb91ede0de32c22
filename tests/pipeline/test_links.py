"""The one pair builder: track pairs, fragment pairs and stitches."""

from __future__ import annotations

import numpy as np

from pipeline.links import LinkBuilder, sample_pairs


def _add(b: LinkBuilder, track, member=None, ref=None, fragments=None, share=None):
    track = np.asarray(track)
    member = np.ones(len(track), bool) if member is None else np.asarray(member)
    ref = np.arange(len(track)) if ref is None else np.asarray(ref)
    return b.add(track, member, ref, fragments, share)


def test_links_track_pairs_join_each_member_to_its_tracks_previous_member():
    b = LinkBuilder()
    _add(b, [5, 6, 0], ref=[10, 11, 12])
    links = _add(b, [6, 5, 7], ref=[20, 21, 22])
    assert links.pairs.tolist() == [[11, 20], [10, 21]]
    assert links.track.tolist() == [6, 5] and links.later.tolist() == [0, 1]


def test_links_a_segment_without_a_sample_holds_no_pair_and_the_track_links_over_it():
    b = LinkBuilder()
    _add(b, [5], ref=[1])
    assert len(_add(b, [5], member=[False], ref=[2]).pairs) == 0
    assert _add(b, [5], ref=[3]).pairs.tolist() == [[1, 3]]


def test_links_fragment_pairs_join_two_different_member_tracks_only():
    b = LinkBuilder()
    _add(b, [5, 6, 0], ref=[10, 11, 12])
    # (this, previous): 1-0 joins tracks 7 and 5; 0-1 is the track link of 6; 1-2 reaches an invalid segment
    links = _add(b, [6, 7], ref=[20, 21], fragments=[[1, 0], [0, 1], [1, 2]], share=[0.4, 0.9, 0.7])
    assert links.fragments.tolist() == [[1, 0]]
    assert links.fragment_refs.tolist() == [[21, 10]]
    assert links.stitch.tolist() == [[5, 7]] and links.share.tolist() == [np.float32(0.4)]


def test_links_gap_drops_fragment_pairs_across_a_left_out_frame_but_keeps_tracks():
    b = LinkBuilder()
    _add(b, [5, 6], ref=[10, 11])
    b.gap()
    links = _add(b, [5, 7], ref=[20, 21], fragments=[[1, 0]], share=[0.5])
    assert len(links.fragments) == 0 and links.pairs.tolist() == [[10, 20]]


def test_links_chain_pairs_consecutive_members_in_order():
    assert LinkBuilder().chain(3, [7, 9, 4]).tolist() == [[7, 9], [9, 4]]
    assert LinkBuilder().chain(3, []).shape == (0, 2)


def test_sample_pairs_orders_pairs_by_frame():
    track = np.array([1, 2, 1, 2, 1])
    frame = np.array([0, 0, 1, 1, 2])
    assert sample_pairs(track, frame).tolist() == [[0, 2], [1, 3], [2, 4]]
