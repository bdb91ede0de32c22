"""The viser viewer end to end without a browser: headless clients connect over the viewer's own
websocket (as a browser tab does), press hotkeys through viser's command messages, and every
outcome is checked through the track service's API."""

from __future__ import annotations

import re
import time
from types import SimpleNamespace

import numpy as np
import pytest

from annotator_ui.client import ApiClient
from annotator_ui.cloud_lod import lod
from annotator_ui.headless import HeadlessClient, is_points
from annotator_ui.panels import AnchorsPanel, JobsPanel, ProgressPanel, StitchesPanel, learning_curve
from annotator_ui.viewer import AnnotatorViewer, ViewerConfig

TRACK_RE = re.compile(r"\*\*Track (\d+)\*\*")


@pytest.fixture
def tab_client(viewer):
    c = HeadlessClient(viewer.url)
    c.wait_for(is_points("/frame/points"))
    yield c
    c.close()


def shown_track(viewer: AnnotatorViewer, client_count: int = 1):
    deadline = time.monotonic() + 10
    while len(viewer.tabs) < client_count:
        assert time.monotonic() < deadline
        time.sleep(0.02)
    return [t.session.track for t in viewer.tabs.values()]


def wait_until(fn, timeout=10.0):
    deadline = time.monotonic() + timeout
    while not fn():
        assert time.monotonic() < deadline, "condition not reached"
        time.sleep(0.02)


def test_viewer_sends_the_frame_points_in_float32(viewer, tab_client, live_api):
    track = shown_track(viewer)[0]
    msg = tab_client.wait_for(is_points("/frame/points"))
    props = msg.fields["props"]
    assert props["precision"] == "float32" and props["points"]["dtype"] == "<f4"
    frame = next(s for s in track["segments"] if s["frame_index"] == viewer.tabs[0].session.frame_index)
    n = props["points"]["nbytes"] // 12
    api = ApiClient(live_api.url, live_api.admin_token)
    assert n == len(lod(api.frame_payload(frame["frame_id"]).points))  # the frame's level of detail
    hl = tab_client.wait_for(is_points("/frame/track"))
    assert 0 < hl.fields["props"]["points"]["nbytes"] // 12 < n  # the track's own points, highlighted
    if len(track["segments"]) > 1:
        tab_client.wait_for(lambda m: m.type == "LineSegmentsMessage" and m.name == "/track/path")
    api.close()


def test_viewer_accept_hotkey_accepts_and_loads_the_next_track(viewer, tab_client, live_api):
    track = shown_track(viewer)[0]
    since = tab_client.mark()
    tab_client.trigger("Accept track")
    tab_client.wait_for(is_points("/track/nodes"), since=since)  # drawn (the cloud stays when the frame does)
    assert live_api.track(track["id"])["status"] == "accepted"
    wait_until(lambda: viewer.tabs[0].session.track_id != track["id"])

    def shows_new_track() -> bool:
        text = tab_client.markdown_containing("**Track ")
        return text is not None and int(TRACK_RE.search(text).group(1)) == viewer.tabs[0].session.track_id

    wait_until(shows_new_track)


def test_viewer_class_hotkey_labels_the_track(viewer, tab_client, live_api):
    track = shown_track(viewer)[0]
    since = tab_client.mark()
    tab_client.trigger("Class cyclist")
    tab_client.wait_for(is_points("/track/nodes"), since=since)  # drawn (the cloud stays when the frame does)
    t = live_api.track(track["id"])
    assert (t["status"], t["label"]) == ("accepted", "cyclist")


def test_viewer_stale_edit_is_notified_and_nothing_is_overwritten(viewer, tab_client, live_api):
    track = shown_track(viewer)[0]
    live_api.admin_act(track["id"], "discard", version=track["version"])  # someone else edits it
    since = tab_client.mark()
    tab_client.trigger("Accept track")
    note = tab_client.wait_for(lambda m: m.type == "NotificationShowMessage", since=since)
    assert "changed" in note.fields["props"]["title"]
    assert live_api.track(track["id"])["status"] == "discarded"  # the other edit stands
    wait_until(lambda: viewer.tabs[0].session.track["version"] == track["version"] + 1)  # reloaded


def test_viewer_two_tabs_of_one_token_show_different_tracks(viewer, tab_client):
    second = HeadlessClient(viewer.url)
    second.wait_for(is_points("/frame/points"))
    tracks = shown_track(viewer, 2)
    assert tracks[0]["id"] != tracks[1]["id"]
    second.close()


def test_viewer_click_on_another_track_opens_it(viewer, tab_client):
    tab = viewer.tabs[0]
    wait_until(lambda: tab.frame_points is not None)
    pts, tracks = tab.frame_points, tab.frame_tracks
    others = np.flatnonzero((tracks > 0) & (tracks != tab.session.track_id))
    target = others[np.argmin(np.linalg.norm(pts[others], axis=1))]  # the nearest point of another track
    origin = np.zeros(3)
    tab._on_click(SimpleNamespace(ray_origin=tuple(origin), ray_direction=tuple(pts[target].astype(float))))
    wait_until(lambda: tab.session.track_id == int(tracks[target]))
    assert not tab.session.from_queue


def test_viewer_undo_hotkey_brings_the_track_back(viewer, tab_client, live_api):
    track = shown_track(viewer)[0]
    since = tab_client.mark()
    tab_client.trigger("Discard track")
    tab_client.wait_for(is_points("/track/nodes"), since=since)  # drawn (the cloud stays when the frame does)
    since = tab_client.mark()
    tab_client.trigger("Undo")
    tab_client.wait_for(is_points("/track/nodes"), since=since)  # drawn (the cloud stays when the frame does)
    assert live_api.track(track["id"])["status"] == "pending"
    wait_until(lambda: viewer.tabs[0].session.track_id == track["id"])


def test_viewer_progress_panel_matches_the_api(viewer, tab_client, live_api):
    panel: ProgressPanel = viewer.tabs[0].progress
    st = panel.refresh()
    api = ApiClient(live_api.url, live_api.admin_token)
    assert st == api.stats(live_api.sequence_id)  # the tab's sequence
    assert f"{st['tracks_reviewed']} reviewed" in panel.gui_summary.content
    points = api.points_progress(live_api.sequence_id)
    assert f"{points['points_in_tracks']:,} points in tracks" in panel.gui_points.content
    api.close()


def test_viewer_jobs_panel_runs_a_job_to_the_end(viewer, tab_client, live_api):
    from app.worker import Worker

    panel: JobsPanel = viewer.tabs[0].jobs
    panel.refresh_types()
    for name, button in panel.gui_buttons.items():  # absent or admin-only types: disabled, not faked
        assert button.disabled == (name not in panel.types or panel.types[name]["admin_only"])
    if "train" in panel.types and panel.types["train"]["admin_only"]:
        assert "need the admin role" in panel.gui_types.content
    job = panel.start("selftest")
    assert job is not None and job["status"] == "queued"
    assert Worker(live_api.settings).run_once()
    wait_until(lambda: panel.job["status"] == "succeeded", timeout=15)
    assert panel.gui_bar.value == pytest.approx(100.0)


def test_viewer_jobs_panel_reports_an_unknown_job_type(viewer, tab_client):
    panel: JobsPanel = viewer.tabs[0].jobs
    notes = []
    panel.notify = lambda title, body, colour: notes.append((title, body))
    assert panel.start("no_such_type") is None and "unknown job type" in notes[0][1]


def test_viewer_jobs_panel_plots_the_learning_curve(viewer, tab_client):
    panel: JobsPanel = viewer.tabs[0].jobs
    job = {"id": 1, "type": "train", "status": "running", "progress": 0.5, "message": "epoch 2",
           "result": {"history": [{"epoch": 1, "loss": 2.0}, {"epoch": 2, "loss": 1.0}]}}
    panel._show(job)
    assert panel.gui_curve is not None and list(panel.gui_curve.data[1]) == [2.0, 1.0]
    assert panel.gui_bar.value == pytest.approx(50.0)
    tab_client.wait_for(lambda m: m.type == "GuiUplotMessage")  # the plot reached the client


def test_viewer_jobs_panel_fills_train_and_predict_params(viewer, tab_client):
    panel: JobsPanel = viewer.tabs[0].jobs
    panel.refresh_types()
    seq = viewer.tabs[0].sequence_id()
    if "train" in panel.types:
        assert panel._params("train")["sequence_ids"] == [seq]
    if "predict" in panel.types:
        assert panel._params("predict").get("sequence_id") == seq


def add_proposals(live_api, n: int) -> list[int]:
    """Anchor proposals as a propose_anchors job would write them (track level, a sample shown)."""
    from sqlalchemy import select

    from app.core.db import Database
    from app.models import AnchorProposal, Segment, Track

    db = Database.from_settings(live_api.settings)
    with db.write() as s:
        tracks = s.scalars(select(Track).where(Track.status == "pending").order_by(Track.id.desc()).limit(n)).all()
        ids = []
        for rank, t in enumerate(tracks):
            seg = s.scalars(select(Segment).where(Segment.track_id == t.id, Segment.sample_index.is_not(None))).first()
            a = AnchorProposal(sequence_id=t.sequence_id, track_id=t.id, proposed_class="car", score=0.9,
                               level="track", strategy="track", rank=rank, segment_id=None if seg is None else seg.id)
            s.add(a)
            s.flush()
            ids.append(a.id)
        s.commit()
    db.dispose()
    return ids


def test_viewer_anchors_panel_confirms_corrects_and_rejects(viewer, tab_client, live_api):
    panel: AnchorsPanel = viewer.tabs[0].anchors
    panel.refresh()
    if not panel.available:  # a service without issue 7's API: a plain notice, nothing to click
        assert "No anchor proposals" in panel.gui_status.content and panel.gui_refresh.disabled
        return
    ids = add_proposals(live_api, 3)
    panel.refresh()
    assert "waiting" in panel.gui_status.content
    api = ApiClient(live_api.url, live_api.admin_token)
    by_id = {a["id"]: a for a in api.get("/anchors", status="proposed", limit=1000)["items"]}
    panel._answer(by_id[ids[0]], "Confirm", "car")
    panel._answer(by_id[ids[1]], "Confirm", "person")  # another class than proposed: a correction
    panel._answer(by_id[ids[2]], "Reject", "car")
    got = {i: api.get(f"/anchors/{i}") for i in ids}
    assert (got[ids[0]]["status"], got[ids[0]]["answer_class"]) == ("confirmed", "car")
    assert (got[ids[1]]["answer_class"], got[ids[1]]["corrected"]) == ("person", True)
    assert got[ids[2]]["status"] == "rejected"
    assert live_api.track(by_id[ids[1]]["track_id"])["label"] == "person"  # a track anchor labels its track
    api.close()


def test_learning_curve_reads_per_epoch_metrics():
    rows = {"history": [{"epoch": 1, "loss": 2.0, "val_f1": 0.3}, {"epoch": 2, "loss": 1.0, "val_f1": 0.6}]}
    c = learning_curve(rows)
    assert list(c["epoch"]) == [1, 2] and list(c["val_f1"]) == [0.3, 0.6]
    cols = learning_curve({"metrics": {"history": {"loss": [3.0, 2.0, 1.5]}}})
    assert list(cols["epoch"]) == [1, 2, 3]
    model = learning_curve({"train_loss": [2.0, 1.0], "val_f": [None, 55.0], "epochs_run": 2})
    assert list(model["loss"]) == [2.0, 1.0] and np.isnan(model["val_f"][0]) and model["val_f"][1] == 55.0
    assert learning_curve({"steps": 3}) is None and learning_curve(None) is None


def test_viewer_without_token_each_tab_signs_in(live_api):
    v = AnnotatorViewer(ViewerConfig(api_url=live_api.url, token=None, port=0))
    try:
        c = HeadlessClient(v.url)
        c.wait_for(lambda m: m.type == "GuiButtonMessage" and m.fields["props"]["label"] == "Sign in")
        handle = next(iter(v.server.get_clients().values()))
        v._sign_in(handle, "tl_wrong", form=None)
        c.wait_for(lambda m: m.type == "NotificationShowMessage" and "Sign-in failed" in m.fields["props"]["title"])
        assert not v.tabs
        v._sign_in(handle, live_api.new_operator(), form=None)
        c.wait_for(is_points("/frame/points"))
        assert v.tabs[handle.client_id].user["role"] == "operator"
        c.close()
    finally:
        v.stop()


def test_viewer_stitches_panel_lists_the_tracks_stitches_and_decides_them(viewer, tab_client, live_api):
    panel: StitchesPanel = viewer.tabs[0].stitches
    api = ApiClient(live_api.url, live_api.admin_token)
    pending = api.get("/stitches", status="pending", limit=1000)
    assert pending["total"] > 0  # the live service ingested a simulated scene with the real pipeline
    st = pending["items"][0]
    viewer.tabs[0].open_track(int(st["track_a_id"]))
    wait_until(lambda: viewer.tabs[0].session.track_id == st["track_a_id"])
    panel.refresh()
    assert f"of track {st['track_a_id']}" in panel.gui_status.content and "pending stitches" in panel.gui_status.content
    panel._decide(st, "One object")
    assert api.get(f"/stitches/{st['id']}")["status"] == "confirmed"
    panel._decide(st, "Different")  # decided on the old version: refused, and said so
    assert api.get(f"/stitches/{st['id']}")["status"] == "confirmed"
    panel._decide(api.get(f"/stitches/{st['id']}"), "Different")
    assert api.get(f"/stitches/{st['id']}")["status"] == "rejected"
    panel._decide(st, f"Show {st['track_b_id']}")
    wait_until(lambda: viewer.tabs[0].session.track_id == st["track_b_id"])
    api.close()


def _predict(live_api, n: int, cls: str, conf: float) -> list[int]:
    """Predictions on n unleased pending tracks, as the model in the loop writes them."""
    from sqlalchemy import select, update

    from app.core.db import Database
    from app.models import Track

    db = Database.from_settings(live_api.settings)
    with db.write() as s:
        ids = list(s.scalars(select(Track.id).where(Track.status == "pending", Track.lease_user_id.is_(None))
                             .order_by(Track.id.desc()).limit(n)).all())
        s.execute(update(Track).where(Track.id.in_(ids)).values(predicted_class=cls, predicted_confidence=conf))
        s.execute(update(Track).where(Track.id.not_in(ids), Track.predicted_class == cls)
                  .values(predicted_class=None, predicted_confidence=None))
        s.commit()
    db.dispose()
    return ids


def test_viewer_model_panel_previews_accepts_and_undoes_a_bulk(viewer, tab_client, live_api):
    from annotator_ui.bulk_panel import BulkPanel

    ids = _predict(live_api, 2, "trunk", 0.97)
    panel: BulkPanel = viewer.tabs[0].bulk
    panel.gui_class.value, panel.gui_confidence.value = "trunk", 0.95
    p = panel.preview()
    assert p["tracks"] == 2 and "**2** pending tracks" in panel.gui_summary.content and not panel.gui_accept.disabled
    bulk = panel.accept()
    assert bulk is not None and bulk["n_tracks"] == 2
    assert {live_api.track(i)["label_source"] for i in ids} == {"bulk"}
    assert "#" in panel.gui_history.content and not panel.gui_undo.disabled
    panel.undo()
    assert {live_api.track(i)["status"] for i in ids} == {"pending"}
    _predict(live_api, 0, "trunk", 0.0)
