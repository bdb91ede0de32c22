"""A real track service for the viewer's tests: the demo's own preparation (simulate a few frames
of the campus scene, upgrade a temporary SQLite database, ingest with the real pipeline), served by
uvicorn in a thread on a free loopback port. Built once per session; every test signs in as its own
operator so that their leases never mix."""

from __future__ import annotations

import itertools
import socket
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import httpx
import pytest

SIM_FRAMES = 6


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@dataclass
class LiveApi:
    url: str  # http://127.0.0.1:PORT (no /api/v1)
    admin_token: str
    operator_token: str
    sequence_id: int
    settings: object
    _names: itertools.count

    def new_operator(self) -> str:
        """A fresh operator's token (one per test keeps review leases apart)."""
        r = httpx.post(
            f"{self.url}/api/v1/users",
            json={"name": f"op{next(self._names)}", "role": "operator"},
            headers={"Authorization": f"Bearer {self.admin_token}"},
        )
        r.raise_for_status()
        return r.json()["token"]

    def admin_act(self, track_id: int, action: str, **body: object) -> dict:
        """An admin's action on a track an operator holds the lease of (an explicit override)."""
        r = httpx.post(f"{self.url}/api/v1/tracks/{track_id}/{action}", params={"override_lease": "true"},
                       json=body, headers={"Authorization": f"Bearer {self.admin_token}"})
        r.raise_for_status()
        return r.json()

    def track(self, track_id: int) -> dict:
        r = httpx.get(f"{self.url}/api/v1/tracks/{track_id}", headers={"Authorization": f"Bearer {self.admin_token}"},
                      timeout=30)  # the 2-core test machine is often loaded: 5 s was not always enough
        r.raise_for_status()
        return r.json()


@pytest.fixture(scope="session")
def live_api(tmp_path_factory: pytest.TempPathFactory) -> Iterator[LiveApi]:
    import uvicorn

    from app.demo import prepare_demo
    from app.main import create_app

    out: Path = tmp_path_factory.mktemp("annotator_api")
    port = free_port()
    info = prepare_demo(out, frames=SIM_FRAMES, seed=0, port=port, log=lambda _m: None)
    settings = info.settings.model_copy(update={"embedded_worker": False})
    server = uvicorn.Server(uvicorn.Config(create_app(settings), host="127.0.0.1", port=port, log_level="warning"))
    thread = threading.Thread(target=server.run, name="live-api", daemon=True)
    thread.start()
    base = f"http://127.0.0.1:{port}"
    deadline = time.monotonic() + 30
    while not server.started:
        assert thread.is_alive() and time.monotonic() < deadline, "the API did not start"
        time.sleep(0.05)
    yield LiveApi(base, info.admin_token, info.operator_token, info.sequence_id, settings, itertools.count(1))
    server.should_exit = True
    thread.join(timeout=10)


@pytest.fixture
def viewer(live_api: LiveApi) -> Iterator[object]:
    """A viewer on the live API, signed in as a new operator, on a free port."""
    from annotator_ui.viewer import AnnotatorViewer, ViewerConfig

    v = AnnotatorViewer(ViewerConfig(api_url=live_api.url, token=live_api.new_operator(), port=0))
    yield v
    v.stop()


@pytest.fixture
def tab(viewer) -> Iterator[object]:
    """The viewer's one tab, driven by a headless client, once its first track is drawn."""
    from annotator_ui.headless import HeadlessClient, is_points
    from tests.annotator_ui.test_viewer import wait_until

    c = HeadlessClient(viewer.url)
    c.wait_for(is_points("/frame/points"))
    wait_until(lambda: len(viewer.tabs) == 1 and viewer.tabs[0].session.track is not None)
    t = next(iter(viewer.tabs.values()))
    t.headless = c
    yield t
    c.close()
