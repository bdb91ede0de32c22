"""The annotator: a viser server where each browser tab reviews tracks of the track service.

`AnnotatorViewer` builds the server; every connecting client gets its own `ClientTab`
(annotator_ui/tab.py: its panels, scene and review session), set up in `on_client_connect` and
kept per client id on the viewer instance (no module globals). The viewer reaches the service only
through `annotator_ui.client.ApiClient`; one `ChangeFeed` keeps every tab's frames and tracks true
to the service.
"""

from __future__ import annotations

import threading
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import Any

import viser

from annotator_ui.change_feed import ChangeFeed
from annotator_ui.client import ApiClient, ApiError
from annotator_ui.cloud_lod import MAX_CLOUD_POINTS, VOXEL_M
from annotator_ui.frame_cache import FrameCache
from annotator_ui.label_set import LabelSets
from annotator_ui.review import QueueCoordinator
from annotator_ui.scene_view import SIDE_PANELS_DELAY_S
from annotator_ui.tab import ClientTab

__all__ = ["AnnotatorViewer", "ClientTab", "ViewerConfig"]

# masks what is typed into the sign-in page's only text field (Chromium and WebKit)
MASK_TOKEN_CSS = "<style>.mantine-TextInput-input{-webkit-text-security:disc}</style>"


@dataclass(frozen=True)
class ViewerConfig:
    api_url: str
    token: str | None = None  # None: each tab signs in with its operator's token
    host: str = "127.0.0.1"
    port: int = 8080
    cache_mb: int = 256
    follow_camera: bool = True
    prefetch: bool = True  # lease and fetch the next track while the operator decides
    cloud_budget: int = MAX_CLOUD_POINTS  # the background cloud's level of detail (annotator_ui.cloud_lod)
    cloud_voxel_m: float = VOXEL_M
    side_panels_delay_s: float | None = SIDE_PANELS_DELAY_S  # None: sample, route and stitches sent with the draw


class AnnotatorViewer:
    """The viser server of the annotator. Non-blocking: `serve_forever()` blocks, `stop()` ends it."""

    def __init__(self, config: ViewerConfig, verbose: bool = False) -> None:
        self.config = config
        self.cache = FrameCache(config.cache_mb * 2**20)
        self.label_sets = LabelSets()  # each sequence's classes, read once
        self.coordinator = QueueCoordinator()
        self.tabs: dict[int, ClientTab] = {}
        self._tabs_lock = threading.Lock()
        self._pool = ThreadPoolExecutor(max_workers=4, thread_name_prefix="annotator-bg")
        self.server = viser.ViserServer(host=config.host, port=config.port, label="tracklabel", verbose=verbose)
        self.server.scene.set_up_direction("+z")
        self.server.initial_camera.position = (-18.0, -18.0, 16.0)
        self.server.initial_camera.look_at = (0.0, 0.0, 0.0)
        self.server.on_client_connect(self._on_connect)
        self.server.on_client_disconnect(self._on_disconnect)
        self.feed = ChangeFeed(self.cache, self.open_tabs)
        self.feed.start()

    @property
    def port(self) -> int:
        return int(self.server.get_port())

    @property
    def url(self) -> str:
        host = "127.0.0.1" if self.config.host in ("0.0.0.0", "::") else self.config.host
        return f"http://{host}:{self.port}"

    def background(self, fn: Any) -> None:
        """Run `fn` off the GUI callback; its errors are printed, never raised into viser."""

        def run() -> None:
            try:
                fn()
            except Exception:  # noqa: BLE001 - a background refresh must not kill the pool
                import traceback

                traceback.print_exc()

        self._pool.submit(run)

    def open_tabs(self) -> list[ClientTab]:
        with self._tabs_lock:
            return list(self.tabs.values())

    def tab(self, client_id: int) -> ClientTab | None:
        with self._tabs_lock:
            return self.tabs.get(client_id)

    # ------------------------------------------------------------------ clients
    def _on_connect(self, client: viser.ClientHandle) -> None:
        if self.config.token:
            self._sign_in(client, self.config.token, form=None)
            return
        gui = client.gui
        gui.configure_theme(control_width="large", dark_mode=True, show_logo=False)  # the review page's theme
        folder = gui.add_folder("Sign in")
        with folder:
            gui.add_markdown("Paste your tracklabel token (`tracklabel user add NAME` prints one).")
            gui.add_html(MASK_TOKEN_CSS)  # a password field: viser's text input has no masked mode
            token = gui.add_text("Token", initial_value="")
            button = gui.add_button("Sign in", color="green")
        button.on_click(lambda _: self._sign_in(client, token.value.strip(), form=folder))

    def _sign_in(self, client: viser.ClientHandle, token: str, form: Any) -> None:
        api = ApiClient(self.config.api_url, token)
        try:
            user = api.me()
        except ApiError as exc:
            api.close()
            msg = "the token was not accepted" if exc.status == 401 else exc.detail
            client.add_notification("Sign-in failed", msg, auto_close_seconds=8.0, color="red")
            if form is None:
                client.gui.add_markdown(f"**The viewer cannot reach the track service:** {msg}")
            return
        if form is not None:
            form.remove()
        tab = ClientTab(self, client, api, user)
        with self._tabs_lock:
            self.tabs[client.client_id] = tab
        tab.start()

    def _on_disconnect(self, client: viser.ClientHandle) -> None:
        with self._tabs_lock:
            tab = self.tabs.pop(client.client_id, None)
        if tab is not None:
            tab.close()
            tab.api.close()

    # ------------------------------------------------------------------ running
    def serve_forever(self) -> None:
        try:
            while True:
                time.sleep(3600)
        except KeyboardInterrupt:
            pass
        finally:
            self.stop()

    def stop(self) -> None:
        with self._tabs_lock:
            tabs = list(self.tabs.values())
            self.tabs.clear()
        self.feed.stop()
        for tab in tabs:
            tab.close()
        self.server.stop()
        self._pool.shutdown(wait=False, cancel_futures=True)
