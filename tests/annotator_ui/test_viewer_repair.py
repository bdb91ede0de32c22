"""The viewer's repair tools, readable track and the fixes of the browser review, with a headless
client connected (tests/annotator_ui/test_viewer.py has the fixtures' pattern)."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from annotator_ui.client import ApiClient, ApiError
from annotator_ui.headless import is_points
from annotator_ui.review_panel import empty_queue_message
from annotator_ui.tab import ClientTab
from pipeline.classes import SAMPLE_CLASSES
from tests.annotator_ui.test_viewer import wait_until


def _open_multi_frame(tab: ClientTab, min_frames: int = 3) -> None:
    for _ in range(60):
        lo, hi = tab.session.frame_range()
        if hi - lo + 1 >= min_frames and tab.session.track["n_points"] > 40:
            return
        tab.run_action("skip")
    pytest.fail("no multi-frame track in the queue")


def test_viewer_class_buttons_show_their_number_keys(tab):
    labels = [*tab.review.buttons["Class 1-4"].options, *tab.review.buttons["Class 5-7"].options]
    assert labels == [f"{i + 1} {name}" for i, name in enumerate(SAMPLE_CLASSES)]


def test_viewer_stitch_rows_stay_in_their_tab_and_follow_the_track(tab, live_api):
    api = ApiClient(live_api.url, live_api.admin_token)
    st = api.get("/stitches", status="pending", limit=1)["items"][0]
    tab.open_track(int(st["track_a_id"]))
    wait_until(lambda: f"of track {st['track_a_id']}" in tab.stitches.gui_status.content)
    rows = tab.stitches._items
    assert rows, tab.stitches.gui_status.content
    assert rows and all(h._impl.parent_container_id == tab.stitches.gui_rows._impl.uuid for h in rows)
    tab.run_action("skip")  # an action: the panel follows the track shown next
    wait_until(lambda: f"of track {tab.session.track_id}" in tab.stitches.gui_status.content)
    api.close()


def test_viewer_slider_goes_back_when_the_frame_cannot_be_drawn(tab, monkeypatch):
    _open_multi_frame(tab)
    shown = tab.session.frame_index
    lo, hi = tab.session.frame_range()
    other = lo if shown != lo else hi

    def outage(*_a, **_k):
        raise ApiError(0, "cannot reach the track service")

    monkeypatch.setattr(tab.cache, "payload", outage)
    tab.playback.gui_frame.value = other  # the operator drags the slider during an outage
    tab.playback._on_slider(SimpleNamespace(client=object()))
    assert tab.session.frame_index == shown and tab.playback.gui_frame.value == shown


def test_viewer_failed_ingest_is_not_all_reviewed():
    api = SimpleNamespace(
        sequences=lambda: [{"id": 3, "name": "seq", "status": "failed", "ingest_job_id": 9}],
        stats=lambda _seq=None: {"tracks": 0},
    )
    text = empty_queue_message(api)
    assert "Ingest of sequence seq (#3) failed" in text and "All tracks are reviewed" not in text


def test_viewer_split_by_plane_then_undo(tab, live_api):
    _open_multi_frame(tab)
    tid = tab.session.track_id
    centre = tab.track_centre()
    T = tab.frame_pose()
    normal = T[:3, :3] @ np.array([1.0, 0.0, 0.0])
    region = {"kind": "halfspace", "normal": normal.tolist(), "offset": float(normal @ (T[:3, :3] @ centre + T[:3, 3]))}
    before = live_api.track(tid)
    tab.split(region, this_frame_only=False)
    after = live_api.track(tid)
    assert after["version"] == before["version"] + 1 and after["n_points"] < before["n_points"]
    assert tab.session.track_id == tid  # the shown track stays
    tab.run_action("undo")
    assert live_api.track(tid)["n_points"] == before["n_points"]


def test_viewer_merge_by_click(tab, live_api):
    a = tab.session.track_id
    api = ApiClient(live_api.url, live_api.admin_token)
    b = next(t["id"] for t in api.list_tracks(status="pending", limit=50)["items"] if t["id"] != a)
    n = live_api.track(a)["n_points"] + live_api.track(b)["n_points"]
    tab.repair.gui_merge_click.value = True
    assert tab.repair.wants_click()
    tab.repair.clicked(b)
    assert live_api.track(b)["status"] == "merged" and live_api.track(a)["n_points"] == n
    assert not tab.repair.wants_click()
    tab.run_action("undo")
    assert live_api.track(b)["status"] == "pending"
    api.close()


def test_viewer_draws_the_track_in_real_colours_and_the_aggregated_view(tab):
    _open_multi_frame(tab)
    c = tab.headless
    mark = c.mark()
    tab.views.gui_aggregate.value = True
    tab.render_frame()
    agg = c.wait_for(is_points("/track/aggregate"), since=mark)
    track = c.wait_for(is_points("/frame/track"), since=mark)
    n_agg, n_track = agg.fields["props"]["points"]["nbytes"] // 12, track.fields["props"]["points"]["nbytes"] // 12
    assert n_agg > n_track  # every kept frame's points, not only this frame's
    assert track.fields["props"]["colors"]["nbytes"] == 3 * n_track  # a colour per point, not one highlight
    c.wait_for(lambda m: m.name == "/frame/outline", since=mark)
