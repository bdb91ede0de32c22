"""The Ground tab (the lasso, issue 35) in a real browser: it renders its controls, and ticking
Draw reaches the viewer, so the next click on the 3D view draws (skips without chromium)."""

from __future__ import annotations

import pytest

from tests.annotator_ui.test_browser import CHROMIUM, page  # noqa: F401 - the fixture
from tests.annotator_ui.test_viewer import wait_until

pytestmark = [pytest.mark.browser, pytest.mark.skipif(CHROMIUM is None, reason="chromium is absent")]


def test_browser_ground_tab_renders_and_draw_reaches_the_viewer(page):  # noqa: F811 - the fixture
    page.get_by_role("tab", name="Ground").click()
    close = page.get_by_role("button", name="Close & label")
    close.wait_for(state="visible", timeout=15_000)
    assert close.is_disabled()  # no vertex yet
    for name in ("Clear", "Undo last region"):
        assert page.get_by_role("button", name=name).is_visible()
    page.get_by_text("Draw", exact=True).click()
    tab = next(iter(page.viewer.tabs.values()))
    wait_until(lambda: tab.ground.drawing)
    assert not page.errors
