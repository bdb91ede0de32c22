"""The viewer in a real browser: Debian's chromium (/usr/bin/chromium, else `chromium` on PATH)
driven by playwright with the flags in ARGS. Skips cleanly where chromium or playwright is absent."""

from __future__ import annotations

import re
import shutil
import time
from pathlib import Path

import numpy as np
import pytest

from annotator_ui.viewer import AnnotatorViewer, ViewerConfig

CHROMIUM = "/usr/bin/chromium" if Path("/usr/bin/chromium").exists() else shutil.which("chromium")
ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
        "--disable-component-update", "--no-first-run"]
CANVAS = "canvas[data-engine]"  # the three.js canvas of the 3D view
TRACK_TEXT = re.compile(r"Track (\d+) \((queue|picked)\)")

pytestmark = [
    pytest.mark.browser,
    pytest.mark.skipif(CHROMIUM is None, reason="chromium is absent"),
]


@pytest.fixture
def page(live_api):
    sync_api = pytest.importorskip("playwright.sync_api")
    viewer = AnnotatorViewer(ViewerConfig(api_url=live_api.url, token=live_api.new_operator(), port=0))
    with sync_api.sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=ARGS)
        pg = browser.new_page(viewport={"width": 1280, "height": 800})
        errors: list[str] = []
        pg.on("pageerror", lambda e: errors.append(str(e)))
        pg.goto(viewer.url)
        pg.wait_for_selector(CANVAS, timeout=30_000)
        pg.get_by_text(TRACK_TEXT).first.wait_for(timeout=30_000)
        pg.viewer = viewer  # type: ignore[attr-defined]
        pg.errors = errors  # type: ignore[attr-defined]
        yield pg
        browser.close()
    viewer.stop()


def shown_track_id(page) -> int:
    return int(TRACK_TEXT.search(page.get_by_text(TRACK_TEXT).first.inner_text()).group(1))


def wait_for_new_track(page, old: int, timeout: float = 15.0) -> int:
    deadline = time.monotonic() + timeout
    while True:
        tid = shown_track_id(page)
        if tid != old:
            return tid
        assert time.monotonic() < deadline, f"track {old} is still shown"
        time.sleep(0.05)


def canvas_colours(page, path: Path) -> int:
    """Screenshot the 3D canvas and count its distinct colours."""
    import cv2

    box = page.locator(CANVAS).first.bounding_box()
    page.screenshot(path=str(path), clip=box)
    img = cv2.imread(str(path), cv2.IMREAD_COLOR)
    return len(np.unique(img.reshape(-1, 3), axis=0))


def test_browser_viewer_draws_the_cloud_and_accept_button_accepts(page, live_api, tmp_path):
    time.sleep(1.5)  # let the first frame's points upload and draw
    colours = canvas_colours(page, tmp_path / "viewer.png")
    assert colours > 200, f"the 3D canvas looks blank ({colours} colours)"
    track_id = shown_track_id(page)
    assert live_api.track(track_id)["status"] == "pending"
    page.get_by_role("button", name="Accept (A)").click()
    deadline = time.monotonic() + 15
    while live_api.track(track_id)["status"] != "accepted":
        assert time.monotonic() < deadline, "the Accept button did not accept the track"
        time.sleep(0.05)
    wait_for_new_track(page, track_id)
    assert not page.errors


def test_browser_review_twenty_tracks_with_hotkeys_only(page, live_api):
    """The issue's "done means": review 20 tracks with hotkeys only, without an error."""
    keys = ["a", "d", "1", "2", "3", "4", "5", "6", "7"]
    expected: dict[int, tuple[str, str | None, int]] = {}
    for i in range(20):
        tid = shown_track_id(page)
        version = live_api.track(tid)["version"]
        key = keys[i % len(keys)]
        cut = i % 5 == 2
        if cut:  # now and then cut the track to the current frame first
            tab = next(iter(page.viewer.tabs.values()))
            cut = tab.session.frame_index != live_api.track(tid)["keep_end"]  # on the last kept frame "]" changes nothing
            page.keyboard.press("]")  # the next key waits for it (same track), as a fast operator types
        page.keyboard.press(key)
        status = {"a": "accepted", "d": "discarded"}.get(key, "accepted")
        label = None if key in "ad" else ["person", "car", "cyclist", "trunk", "bush", "building", "unknown"][int(key) - 1]
        expected[tid] = (status, label, version + (2 if cut else 1))  # "]" is an edit of its own
        wait_for_new_track(page, tid)
    for tid, (status, label, version) in expected.items():
        t = live_api.track(tid)
        assert (t["status"], t["label"], t["version"]) == (status, label, version), tid
    assert len(expected) == 20
    assert not page.errors
    assert page.locator("text=Action failed").count() == 0 and page.locator("text=Not saved").count() == 0
