"""The top and side views sit beside the 3D view, in full sight, not below the fold of the
control panel (issue 37), in a real browser (skips without chromium)."""

from __future__ import annotations

import pytest

from tests.annotator_ui.test_browser import CANVAS, CHROMIUM, page  # noqa: F401 - the fixture

pytestmark = [pytest.mark.browser, pytest.mark.skipif(CHROMIUM is None, reason="chromium is absent")]


def test_browser_top_and_side_views_beside_the_3d_view(page):  # noqa: F811 - the fixture
    panel_x = page.get_by_text("Track colours").first.bounding_box()["x"]  # the control panel (right)
    page.get_by_text("Top and side views").first.click()
    for label in ("Top view (1 m grid)", "Side view (1 m grid)"):
        view = page.get_by_text(label).first
        view.wait_for(state="visible", timeout=15_000)
        box = view.bounding_box()
        assert box["x"] + box["width"] < panel_x  # left of the control panel: beside the 3D view
        assert 0 <= box["y"] and box["y"] + box["height"] <= 800  # in sight without scrolling
    canvas = page.locator(CANVAS).bounding_box()
    assert canvas["width"] > 600  # the 3D view keeps most of the page
