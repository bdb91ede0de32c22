"""The viewer shows what the service holds (issue 37), in a real browser (chromium + playwright,
demo scene; skips without chromium): after a split and a merge every tab draws the service's
point counts; a double `A` accepts one track and says so; split -> undo -> split gives a fresh id
that an old edit cannot reach; with two sequences the queue stays in the chosen one."""

from __future__ import annotations

import shutil
import threading
import time

import httpx
import pytest

from annotator_ui.viewer import AnnotatorViewer, ViewerConfig
from tests.annotator_ui.conftest import SIM_FRAMES, free_port
from tests.annotator_ui.test_browser import (
    ARGS,
    CANVAS,
    CHROMIUM,
    TRACK_TEXT,
    shown_track_id,
    wait_for_new_track,
)

pytestmark = [pytest.mark.browser, pytest.mark.skipif(CHROMIUM is None, reason="chromium is absent")]


@pytest.fixture
def browser():
    sync_api = pytest.importorskip("playwright.sync_api")
    with sync_api.sync_playwright() as p:
        b = p.chromium.launch(executable_path=CHROMIUM, args=ARGS)
        yield b
        b.close()


def open_page(browser, viewer):
    page = browser.new_page(viewport={"width": 1400, "height": 900})
    page.goto(viewer.url)
    page.wait_for_selector(CANVAS, timeout=30_000)
    page.get_by_text(TRACK_TEXT).first.wait_for(timeout=30_000)
    return page


def wait(fn, timeout=20.0, what="condition"):
    deadline = time.monotonic() + timeout
    while not fn():
        assert time.monotonic() < deadline, f"{what} not reached"
        time.sleep(0.05)


def tabs_of(viewer, n):
    wait(lambda: len(viewer.tabs) == n and all(t.session.track is not None for t in viewer.tabs.values()), what=f"{n} tabs")
    return list(viewer.tabs.values())


def get(url, token, path, **params):
    r = httpx.get(f"{url}/api/v1{path}", params=params, headers={"Authorization": f"Bearer {token}"}, timeout=60)
    r.raise_for_status()
    return r.json()


def service_points(live_api, track_id, frame_index):
    """The service's point count of a track in one frame (0 without a segment there)."""
    t = live_api.track(track_id)
    return sum(s["n_points"] for s in t["segments"] if s["frame_index"] == frame_index)


def draws_service_points(tab, live_api):
    """The tab's frame shows its track with as many points as the service holds there."""
    tid, fi = tab.session.track_id, tab.session.frame_index
    return tab.frame_tracks is not None and int((tab.frame_tracks == tid).sum()) == service_points(live_api, tid, fi)


def biggest_pending(live_api):
    tracks = get(live_api.url, live_api.admin_token, "/tracks", sequence_id=live_api.sequence_id, status="pending",
                 limit=50, sort="-n_points")["items"]
    return next(t for t in tracks if t["length"] >= 2)


def halfspace_through(tab):
    """A plane through the shown track's centre (world frame): about half its points go."""
    centre = tab.track_centre()
    T = tab.frame_pose()
    c_world = T[:3, :3] @ centre + T[:3, 3]
    return {"kind": "halfspace", "normal": [1.0, 0.0, 0.0], "offset": float(c_world[0])}


def test_browser_split_and_merge_are_drawn_with_the_service_points_in_both_tabs(browser, live_api):
    viewer = AnnotatorViewer(ViewerConfig(api_url=live_api.url, token=live_api.new_operator(), port=0))
    try:
        page1 = open_page(browser, viewer)
        tab1 = tabs_of(viewer, 1)[0]
        target = biggest_pending(live_api)
        tab1.open_track(target["id"])
        page2 = open_page(browser, viewer)  # a second tab of the same viewer (its frame cache is shared)
        tab2 = next(t for t in tabs_of(viewer, 2) if t is not tab1)
        tab2.open_track(target["id"])  # both draw the track before it is cut
        wait(lambda: draws_service_points(tab2, live_api), what="tab 2 drawing the track")
        before = int((tab1.frame_tracks == target["id"]).sum())

        tab1.split(halfspace_through(tab1), False)
        new_id = max(t["id"] for t in get(live_api.url, live_api.admin_token, "/tracks",
                                           sequence_id=live_api.sequence_id, limit=500)["items"])
        assert live_api.track(target["id"])["version"] == target["version"] + 1
        wait(lambda: draws_service_points(tab1, live_api), what="tab 1 drawing the cut track as the service holds it")
        assert int((tab1.frame_tracks == target["id"]).sum()) < before
        wait(lambda: draws_service_points(tab2, live_api), what="tab 2 following the split")
        page2.get_by_text(f"Track {target['id']}").first.wait_for(timeout=10_000)
        tab2.open_track(new_id)  # the cut-off part, drawn with its points in the second tab
        wait(lambda: tab2.session.track_id == new_id and draws_service_points(tab2, live_api)
             and service_points(live_api, new_id, tab2.session.frame_index) > 0, what="tab 2 drawing the new track")
        page2.get_by_text(f"Track {new_id}").first.wait_for(timeout=10_000)

        tab2.open_track(target["id"])
        tab1.merge(new_id)  # join the part back: both tabs draw the joined track's points
        assert live_api.track(new_id)["status"] == "merged"
        wait(lambda: draws_service_points(tab1, live_api), what="tab 1 drawing the merged track")
        wait(lambda: draws_service_points(tab2, live_api), what="tab 2 following the merge")
        assert int((tab2.frame_tracks == new_id).sum()) == 0  # no point left with the merged-away id
        page1.get_by_text(f"Track {target['id']}").first.wait_for(timeout=10_000)
    finally:
        viewer.stop()


def test_browser_double_a_accepts_one_track_and_says_so(browser, live_api):
    viewer = AnnotatorViewer(ViewerConfig(api_url=live_api.url, token=live_api.new_operator(), port=0))
    try:
        page = open_page(browser, viewer)
        time.sleep(0.5)
        first = shown_track_id(page)
        # Both presses in one task of the page: no message of the service (the next track's
        # draw) can be handled between them, however fast the next track comes. Two
        # `keyboard.press` calls are two round trips, between which a prefetched track can be
        # drawn, and the second press then rightly accepts it.
        page.evaluate("""() => { for (let i = 0; i < 2; i++) for (const type of ['keydown', 'keyup'])
            document.body.dispatchEvent(new KeyboardEvent(type, {key: 'a', code: 'KeyA', bubbles: true})); }""")
        second = wait_for_new_track(page, first)
        wait(lambda: "Key ignored" in page.content(), timeout=10, what="the notice of the ignored key")
        time.sleep(2.0)  # any late action would have landed by now
        assert live_api.track(first)["status"] == "accepted"
        assert live_api.track(second)["status"] == "pending"
        assert shown_track_id(page) == second
    finally:
        viewer.stop()


def test_browser_split_undo_split_gives_a_fresh_id_and_the_old_edit_is_refused(browser, live_api):
    viewer = AnnotatorViewer(ViewerConfig(api_url=live_api.url, token=live_api.new_operator(), port=0))
    try:
        page = open_page(browser, viewer)
        tab = tabs_of(viewer, 1)[0]
        target = biggest_pending(live_api)
        tab.open_track(target["id"])
        region = halfspace_through(tab)

        def newest() -> dict:
            return max(get(live_api.url, live_api.admin_token, "/tracks", sequence_id=live_api.sequence_id,
                           limit=500)["items"], key=lambda t: t["id"])

        tab.split(region, False)
        first = newest()
        page.keyboard.press("z")  # undo in the browser
        wait(lambda: newest()["id"] != first["id"], what="the undo removing the split's track")
        wait(lambda: tab.session.track is not None and tab.session.track["version"] == target["version"] + 2,
             what="the tab showing the restored track")
        tab.split(region, False)
        second = newest()
        assert second["id"] != first["id"]
        r = httpx.post(f"{live_api.url}/api/v1/tracks/{first['id']}/label", json={"version": first["version"], "label": "car"},
                       headers={"Authorization": f"Bearer {live_api.admin_token}"}, timeout=60)
        assert r.status_code in (404, 409), r.text
        assert live_api.track(second["id"])["status"] == "pending"
    finally:
        viewer.stop()


@pytest.fixture(scope="module")
def two_sequences(tmp_path_factory, live_api):
    """A service of its own with the demo sequence ingested twice (two sequences, same frames)."""
    import uvicorn

    from app.demo import prepare_demo
    from app.label import Source, prepare
    from app.main import create_app

    out = tmp_path_factory.mktemp("two_sequences")
    port = free_port()
    info = prepare_demo(out, frames=SIM_FRAMES, seed=0, port=port, log=lambda _m: None)
    shutil.copytree(info.settings.data_dir / "sequence", info.settings.data_dir / "second")
    second = prepare(info.settings, Source(info.settings.data_dir / "second", name="second", fmt="kitti"), log=lambda _m: None)
    settings = info.settings.model_copy(update={"embedded_worker": False})
    server = uvicorn.Server(uvicorn.Config(create_app(settings), host="127.0.0.1", port=port, log_level="warning"))
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    wait(lambda: server.started, timeout=30, what="the second service")
    yield f"http://127.0.0.1:{port}", info.operator_token, info.admin_token, info.sequence_id, second.sequence_id
    server.should_exit = True
    thread.join(timeout=10)


def test_browser_queue_stays_in_the_chosen_sequence(browser, two_sequences):
    url, operator, admin, first_seq, second_seq = two_sequences
    viewer = AnnotatorViewer(ViewerConfig(api_url=url, token=operator, port=0))
    try:
        page = open_page(browser, viewer)
        tab = tabs_of(viewer, 1)[0]
        page.locator("input[value*='(#']").first.click()
        page.get_by_role("option", name=f"second (#{second_seq})").click()
        page.evaluate("document.activeElement.blur()")  # keys go to the viewer, not the picker
        wait(lambda: int(tab.session.track["sequence_id"]) == second_seq, what="the queue switching to the chosen sequence")
        page.get_by_text("sequence second").first.wait_for(timeout=10_000)
        seen = []
        for _ in range(8):
            tid = shown_track_id(page)
            seen.append(get(url, admin, f"/tracks/{tid}")["sequence_id"])
            page.keyboard.press("s")
            wait_for_new_track(page, tid)
        assert set(seen) == {second_seq}, seen
        pending_first = get(url, admin, "/tracks", sequence_id=first_seq, status="pending", limit=1)["total"]
        assert pending_first > 0  # the other sequence still had tracks to hand out
    finally:
        viewer.stop()
