"""The readable-geometry parts of the viewer: the cut preview counts what a cut takes, far or
sparse tracks open aggregated, the key help from the one
action table."""

from __future__ import annotations

import time

import numpy as np

from annotator_ui.actions import ACTIONS, key_help
from annotator_ui.cut_preview import gizmo_scale, inside_box
from annotator_ui.track_views_panel import FAR_M, SPARSE_POINTS, hard_to_read
from tests.annotator_ui.test_viewer_repair import _open_multi_frame


def test_readable_inside_box_counts_the_points_of_a_rotated_box():
    pts = np.array([[0.0, 0.0, 0.0], [0.9, 0.0, 0.0], [0.0, 0.9, 0.0], [2.0, 0.0, 0.0]], np.float32)
    assert inside_box(pts, np.zeros(3), np.eye(3), np.array([2.0, 2.0, 2.0])).tolist() == [True, True, True, False]
    R = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])  # 90 degrees about z
    long_x = inside_box(pts, np.zeros(3), np.eye(3), np.array([4.2, 0.5, 0.5]))
    long_y = inside_box(pts, np.zeros(3), R, np.array([4.2, 0.5, 0.5]))  # its long side now along y
    assert long_x.tolist() == [True, True, False, True] and long_y.tolist() == [True, False, True, False]


def test_readable_gizmo_follows_the_track_size():
    small, big = np.random.default_rng(0).normal(size=(50, 3)) * 0.2, np.random.default_rng(0).normal(size=(50, 3)) * 4
    assert gizmo_scale(small) < gizmo_scale(big) <= 8.0 and gizmo_scale(np.zeros((0, 3))) == 1.5


def test_readable_far_or_sparse_tracks_open_aggregated():
    seg = {"in_kept_range": True}
    assert hard_to_read({"segments": [{**seg, "n_points": SPARSE_POINTS - 1}], "mean_range": 5.0})
    assert hard_to_read({"segments": [{**seg, "n_points": 5000}], "mean_range": FAR_M + 1})
    assert not hard_to_read({"segments": [{**seg, "n_points": 5000}], "mean_range": 10.0})


def test_readable_key_help_lists_every_key_of_the_table():
    text = key_help()
    assert "**A** accept" in text and "**1-7** class" in text and "**H** / **P**" in text
    assert len({a.key for a in ACTIONS}) == len(ACTIONS)  # one row per key


def test_readable_cut_preview_counts_what_the_cut_takes(tab, live_api):  # noqa: F811 - the fixture
    _open_multi_frame(tab)
    tid = tab.session.track_id
    pts = tab.track_points()
    tab.repair.gui_show_box.value = True
    tab.repair._toggle_gizmo()
    lo, hi = pts.min(0), pts.max(0)
    centre = np.array([lo[0], (lo[1] + hi[1]) / 2, (lo[2] + hi[2]) / 2])  # the box holds the lower half in x
    tab.repair.gui_size.value = (float(hi[0] - lo[0]), float(hi[1] - lo[1]) + 0.2, float(hi[2] - lo[2]) + 0.2)
    # the client echoes the gizmo it was sent (its first position, the track's centre) a moment
    # after; the panel keeps a centre typed before that echo, but an echo can still race the
    # typed value once in a while, so the operator types after it here
    time.sleep(0.5)
    tab.repair.gui_centre.value = tuple(float(v) for v in centre)
    tab.repair._typed_centre()  # as when the operator types the centre
    time.sleep(0.3)
    assert np.allclose(tab.repair.gizmo.position, centre)
    n = tab.repair.preview()
    assert 0 < n < len(pts) and f"**{n}** of {len(pts)}" in tab.repair.gui_preview.content
    before = live_api.track(tid)["n_points"]
    tab.repair.cut("box", this_frame_only=True)
    assert live_api.track(tid)["n_points"] == before - n  # exactly the previewed points went
    tab.run_action("undo")


def test_readable_route_map_marks_the_route_and_the_track():
    from annotator_ui.route_map import ROUTE, SEEN_FROM, TRACK, route_image

    pose = lambda x: [1, 0, 0, x, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1]  # noqa: E731 - a sensor at (x, 0)
    frames = {i: {"pose": pose(float(i))} for i in range(10)}
    track = {"segments": [{"frame_index": 8, "centroid_world": [8.0, 5.0, 0.0]}]}
    img = route_image(track, frames)
    colours = {tuple(c) for c in img.reshape(-1, 3)}
    assert {ROUTE, SEEN_FROM, TRACK} <= colours
    rows, _ = np.nonzero(np.all(img == TRACK, axis=2))
    rows_route, _ = np.nonzero(np.all(img == ROUTE, axis=2))
    assert rows.mean() < rows_route.mean()  # the track lies north of the route (y up)



def test_readable_cut_preview_of_a_truncated_track_counts_what_the_cut_takes(tab, live_api):  # noqa: F811
    """The preview counts the shown frame's points, and the service's count of the kept frames
    falls by exactly that many; frames truncated away stay out of it."""
    _open_multi_frame(tab)
    tid = tab.session.track_id
    lo, _hi = tab.session.frame_range()
    tab.session.set_frame(lo + 1)
    tab.run_action("truncate_before")
    tab.open_track(tid)
    pts = tab.track_points()
    tab.repair.gui_show_box.value = True
    tab.repair._toggle_gizmo()
    a, b = pts.min(0), pts.max(0)
    tab.repair.gui_size.value = (float(b[0] - a[0]), float(b[1] - a[1]) + 0.2, float(b[2] - a[2]) + 0.2)
    tab.repair.gui_centre.value = (float(a[0]), float(a[1] + b[1]) / 2, float(a[2] + b[2]) / 2)
    tab.repair._typed_centre()
    n = tab.repair.preview()
    before = live_api.track(tid)["n_points"]
    tab.repair.cut("box", this_frame_only=True)
    assert 0 < n < len(pts) and live_api.track(tid)["n_points"] == before - n
    tab.run_action("undo")  # the cut
    tab.run_action("undo")  # the truncation: the shared service's track as it was
