"""Track repair in a real browser (chromium + playwright, demo scene): split a track that holds
two simulated objects with the cut box, label both parts, check the SemanticKITTI export, undo;
merge the two tracks of a stitch; the aggregated view; the page layout fixes. Screenshots of the
split in progress and of the aggregated view go to build/screenshots/ (`make screenshots` writes
them to docs/, where the README shows them). Skips without chromium."""

from __future__ import annotations

import io
import tarfile
import time
from pathlib import Path

import httpx
import numpy as np
import pytest

from annotator_ui.viewer import AnnotatorViewer, ViewerConfig
from pipeline.classes import SAMPLE_CLASSES, to_ours
from tests.annotator_ui.test_browser import ARGS, CANVAS, CHROMIUM
from tests.conftest import SCREENSHOTS

CAR = 10  # the SemanticKITTI id the simulator writes

pytestmark = [pytest.mark.browser, pytest.mark.skipif(CHROMIUM is None, reason="chromium is absent")]


@pytest.fixture
def browser(live_api):
    sync_api = pytest.importorskip("playwright.sync_api")
    with sync_api.sync_playwright() as p:
        b = p.chromium.launch(executable_path=CHROMIUM, args=ARGS)
        yield b
        b.close()


def open_viewer(browser, live_api, width=1400, height=900, token=True):
    viewer = AnnotatorViewer(ViewerConfig(api_url=live_api.url, token=live_api.new_operator() if token else None, port=0))
    page = browser.new_page(viewport={"width": width, "height": height})
    page.errors = []
    page.on("pageerror", lambda e: page.errors.append(str(e)))
    page.goto(viewer.url)
    page.wait_for_selector(CANVAS, timeout=30_000)
    return viewer, page


def wait(fn, timeout=20.0, what="condition"):
    deadline = time.monotonic() + timeout
    while not fn():
        assert time.monotonic() < deadline, f"{what} not reached"
        time.sleep(0.05)


def the_tab(viewer):
    wait(lambda: len(viewer.tabs) == 1 and next(iter(viewer.tabs.values())).session.track is not None, what="a tab")
    return next(iter(viewer.tabs.values()))


def api(live_api, method, path, **kw):
    r = httpx.request(method, f"{live_api.url}/api/v1{path}", headers={"Authorization": f"Bearer {live_api.admin_token}"},
                      timeout=60, **kw)
    r.raise_for_status()
    return r


def frame_points(live_api, frame):
    """(world points (N, 3), track id (N,), input row (N,)) of a frame's points, from its artifact."""
    from sqlalchemy import select

    from app.core.db import Database
    from app.models import Frame

    db = Database.from_settings(live_api.settings)
    with db.read() as s:
        rel = s.scalar(select(Frame.artifact).where(Frame.id == frame["id"]))
    db.dispose()
    z = np.load(Path(live_api.settings.artifacts_path) / rel)
    rows = np.flatnonzero(z["input_rows"]) if "input_rows" in z.files else np.arange(len(z["points"]))
    T = np.asarray(frame["pose"]).reshape(4, 4)
    return z["points"].astype(np.float64) @ T[:3, :3].T + T[:3, 3], z["track"], rows


def truth_of(live_api, frame):
    """(M,) uint32 simulator label of each input row of the frame."""
    return np.fromfile(Path(live_api.settings.data_dir) / "sequence" / "labels" / f"{frame['name']}.label", np.uint32)


def ground_truth(live_api, frames, track_id):
    """(world points, instance, semantic) of the track's points over `frames`."""
    pts, inst, sem = [], [], []
    for f in frames:
        world, track, rows = frame_points(live_api, f)
        m = track == track_id
        lab = truth_of(live_api, f)[rows[m]]
        pts.append(world[m]), inst.append(lab >> 16), sem.append(lab & 0xFFFF)
    return np.concatenate(pts), np.concatenate(inst), np.concatenate(sem)


def find_two_objects(live_api, frames):
    """A pending track of two simulated objects that a box separates (a hedge against a wall, a
    trunk under its crown, two cars bumper to bumper): the track, the world points of the smaller
    object (the one the box cuts off), and the instance and class of each (kept, cut off). The
    two hold 97 % of the track's points and the cut-off one's box under 1 % of the other's."""
    tracks = api(live_api, "GET", "/tracks", params={"sequence_id": live_api.sequence_id, "status": "pending",
                                                     "limit": 500, "sort": "-n_points"}).json()["items"]
    for t in tracks:
        if t["length"] < 2:
            continue
        pts, inst, sem = ground_truth(live_api, [f for f in frames if t["keep_start"] <= f["index"] <= t["keep_end"]], t["id"])
        ids, counts = np.unique(inst[inst > 0], return_counts=True)
        if len(ids) < 2:
            continue
        big, small = ids[np.argsort(-counts)[:2]]
        kept, cut = inst == big, inst == small
        if cut.sum() < 100 or (kept | cut).mean() < 0.97:
            continue
        lo, hi = pts[cut].min(0), pts[cut].max(0)
        stray = np.all((pts[kept] >= lo - 0.05) & (pts[kept] <= hi + 0.05), axis=1).mean()
        if stray < 0.01:
            classes = [SAMPLE_CLASSES[int(to_ours(sem[m][:1])[0])] for m in (kept, cut)]
            return t, pts[cut], (int(big), int(small)), classes
    pytest.skip("the demo scene has no track of two objects that a box separates")


def semantickitti(live_api):
    tar = tarfile.open(fileobj=io.BytesIO(api(live_api, "GET", f"/exports/semantickitti/{live_api.sequence_id}").content))
    return {Path(n).stem: np.frombuffer(tar.extractfile(n).read(), np.uint32) for n in tar.getnames() if n.endswith(".label")}


def test_browser_split_two_objects_with_the_box_label_both_export_undo(browser, live_api):
    from pipeline.classes import SEMANTICKITTI_WRITE_ID

    frames = api(live_api, "GET", f"/sequences/{live_api.sequence_id}/frames", params={"limit": 1000}).json()["items"]
    track, cut_world, (kept_inst, cut_inst), (kept_class, cut_class) = find_two_objects(live_api, frames)
    tid, n_before = track["id"], track["n_points"]
    viewer, page = open_viewer(browser, live_api)
    try:
        tab = the_tab(viewer)
        tab.review.gui_goto.value = str(tid)
        page.get_by_role("button", name="Open track").click()
        wait(lambda: tab.session.track_id == tid, what="the track opened")
        page.get_by_role("tab", name="Repair").click()
        page.get_by_text("Show cut box / plane").click()
        wait(lambda: tab.repair.gizmo is not None, what="the cut box")
        # where an operator drags the gizmo to: around the smaller object (in the shown frame's scene)
        T = tab.frame_pose()
        local = (cut_world - T[:3, 3]) @ T[:3, :3]
        lo, hi = local.min(0) - 0.05, local.max(0) + 0.05
        tab.repair.gizmo.position = tuple((lo + hi) / 2)
        tab.repair.gui_size.value = tuple(hi - lo)
        time.sleep(1.0)
        page.screenshot(path=str(SCREENSHOTS / "split_in_progress.png"))
        page.get_by_role("button", name="All kept frames").first.click()
        wait(lambda: api(live_api, "GET", f"/tracks/{tid}").json()["version"] == track["version"] + 1, what="the split")
        split = [e for e in api(live_api, "GET", f"/tracks/{tid}/events").json() if e["action"] == "split"][-1]
        new_id = split["detail"]["new_track"]
        new = api(live_api, "GET", f"/tracks/{new_id}").json()
        # label both parts with the number keys (1 person ... 7 unknown)
        page.keyboard.press(str(SAMPLE_CLASSES.index(kept_class) + 1))
        wait(lambda: api(live_api, "GET", f"/tracks/{tid}").json()["label"] == kept_class, what="the kept part's class")
        tab.review.gui_goto.value = str(new_id)
        page.get_by_role("tab", name="Review").click()
        page.get_by_role("button", name="Open track").click()
        # a key pressed before the client has drawn the track is ignored (it was meant for the old one)
        wait(lambda: getattr(tab.scene.shown, "track_id", None) == new_id, what="the cut-off track on screen")
        page.keyboard.press(str(SAMPLE_CLASSES.index(cut_class) + 1))
        wait(lambda: api(live_api, "GET", f"/tracks/{new_id}").json()["label"] == cut_class, what="the cut-off part's class")

        labels = semantickitti(live_api)
        got, truth = [], []
        for f in frames:
            if track["keep_start"] <= f["index"] <= track["keep_end"]:
                _, tracks, rows = frame_points(live_api, f)
                mine = rows[np.isin(tracks, [tid, new_id])]
                got.append(labels[f["name"]][mine])
                truth.append(truth_of(live_api, f)[mine] >> 16)
        got, truth = np.concatenate(got), np.concatenate(truth)
        # each object's points carry its part's class and instance (the track's key)
        kept_label = SEMANTICKITTI_WRITE_ID[kept_class] | (track["key"] << 16)
        cut_label = SEMANTICKITTI_WRITE_ID[cut_class] | (new["key"] << 16)
        assert np.mean(got[truth == cut_inst] == cut_label) >= 0.99
        assert np.mean(got[truth == kept_inst] == kept_label) >= 0.99

        for _ in range(3):  # the two classes, the split
            page.keyboard.press("z")
            time.sleep(0.5)
        wait(lambda: api(live_api, "GET", f"/tracks/{tid}").json()["n_points"] == n_before, what="the undo")
        assert httpx.get(f"{live_api.url}/api/v1/tracks/{new_id}",
                         headers={"Authorization": f"Bearer {live_api.admin_token}"}).status_code == 404
        assert not page.errors
    finally:
        page.close()
        viewer.stop()


def test_browser_merge_the_tracks_of_a_stitch(browser, live_api):
    st = api(live_api, "GET", "/stitches", params={"status": "pending", "limit": 50}).json()["items"]
    pending = [s for s in st if api(live_api, "GET", f"/tracks/{s['track_b_id']}").json()["status"] == "pending"
               and api(live_api, "GET", f"/tracks/{s['track_a_id']}").json()["status"] == "pending"]
    assert pending, "the demo scene has no stitch of two pending tracks"
    a, b = int(pending[0]["track_a_id"]), int(pending[0]["track_b_id"])
    n = api(live_api, "GET", f"/tracks/{a}").json()["n_points"] + api(live_api, "GET", f"/tracks/{b}").json()["n_points"]
    viewer, page = open_viewer(browser, live_api)
    try:
        tab = the_tab(viewer)
        tab.review.gui_goto.value = str(a)
        page.get_by_role("button", name="Open track").click()
        wait(lambda: tab.session.track_id == a, what="track a opened")
        page.get_by_role("tab", name="Stitches").click()
        wait(lambda: f"of track {a}" in tab.stitches.gui_status.content, what="the track's stitches")
        page.get_by_role("button", name="Merge").first.click()
        wait(lambda: api(live_api, "GET", f"/tracks/{b}").json()["status"] == "merged", what="the merge")
        assert api(live_api, "GET", f"/tracks/{a}").json()["n_points"] == n
        page.keyboard.press("z")
        wait(lambda: api(live_api, "GET", f"/tracks/{b}").json()["status"] == "pending", what="the undo")
        assert not page.errors
    finally:
        page.close()
        viewer.stop()


def test_browser_aggregated_view_and_orthographic_images(browser, live_api):
    viewer, page = open_viewer(browser, live_api)
    try:
        tab = the_tab(viewer)
        frames = api(live_api, "GET", f"/sequences/{live_api.sequence_id}/frames", params={"limit": 1000}).json()["items"]
        tracks = api(live_api, "GET", "/tracks", params={"sequence_id": live_api.sequence_id, "status": "pending",
                                                         "min_length": 5, "sort": "-n_points", "limit": 30}).json()["items"]
        target = next(t for t in tracks if np.mean(ground_truth(live_api, frames, t["id"])[2] == CAR) > 0.9)
        tab.review.gui_goto.value = str(target["id"])
        page.get_by_role("button", name="Open track").click()
        wait(lambda: tab.session.track_id == target["id"], what="the track opened")
        page.get_by_text("Aggregate kept frames").click()
        wait(lambda: tab.views.aggregated, what="the aggregate switch")
        time.sleep(2.0)  # the kept frames' payloads load, the cloud and images are drawn
        page.screenshot(path=str(SCREENSHOTS / "aggregated_view.png"))
        assert not page.errors
    finally:
        page.close()
        viewer.stop()


def test_browser_key_help_is_visible_without_scrolling_at_1400x900(browser, live_api):
    viewer, page = open_viewer(browser, live_api, 1400, 900)
    try:
        the_tab(viewer)
        help_text = page.get_by_text("truncate before / after").first
        help_text.wait_for(timeout=20_000)
        box = help_text.bounding_box()
        assert box is not None and box["y"] + box["height"] <= 900
        assert page.get_by_role("button", name="1 person").count() == 1  # number keys on the class buttons
    finally:
        page.close()
        viewer.stop()


def test_browser_sign_in_page_is_dark_and_masks_the_token(browser, live_api):
    viewer, page = open_viewer(browser, live_api, token=False)
    try:
        field = page.get_by_role("textbox").first
        field.wait_for(timeout=20_000)
        assert field.evaluate("e => getComputedStyle(e).webkitTextSecurity") == "disc"
        background = page.evaluate("() => getComputedStyle(document.querySelector('.mantine-Paper-root, body')).backgroundColor")
        r, g, b = (int(v) for v in background[background.index("(") + 1 : background.index(")")].split(",")[:3])
        assert max(r, g, b) < 80, background
    finally:
        page.close()
        viewer.stop()
