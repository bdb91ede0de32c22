"""The API docs page renders in chromium with every request off the API's own host refused: its
swagger-ui assets come from the package (app/api/docs.py), not a CDN. Skips without chromium."""

from __future__ import annotations

import threading
import time

import pytest

from tests.annotator_ui.conftest import free_port
from tests.annotator_ui.test_browser import ARGS, CHROMIUM

pytestmark = [pytest.mark.browser, pytest.mark.skipif(CHROMIUM is None, reason="chromium is absent")]


@pytest.fixture
def served(tmp_path):
    import uvicorn

    from app.core.config import Settings
    from app.core.migrate import upgrade
    from app.main import create_app

    settings = Settings(data_dir=tmp_path, embedded_worker=False)
    upgrade(settings.db_url)
    port = free_port()
    server = uvicorn.Server(uvicorn.Config(create_app(settings), host="127.0.0.1", port=port, log_level="warning"))
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    deadline = time.monotonic() + 30
    while not server.started:
        assert thread.is_alive() and time.monotonic() < deadline, "the API did not start"
        time.sleep(0.05)
    yield f"http://127.0.0.1:{port}"
    server.should_exit = True
    thread.join(timeout=10)


def test_docs_page_renders_with_the_network_blocked(served):
    sync_api = pytest.importorskip("playwright.sync_api")
    refused: list[str] = []
    with sync_api.sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=ARGS)
        page = browser.new_page()

        def only_local(route):
            if route.request.url.startswith(served):
                route.continue_()
            else:
                refused.append(route.request.url)
                route.abort()

        page.route("**/*", only_local)
        page.goto(f"{served}/api/v1/docs")
        page.locator(".opblock").first.wait_for(timeout=30_000)  # one block per operation, drawn by swagger-ui
        operations = page.locator(".opblock").count()
        title = page.locator(".swagger-ui .title").first.inner_text()
        browser.close()
    assert not refused, f"the docs page asked for {refused}"
    assert operations > 20 and "tracklabel" in title
