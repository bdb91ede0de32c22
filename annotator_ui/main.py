"""Starting the annotator: `tracklabel annotate --api URL --token T [--port 8080]`, or next to the
API from `tracklabel serve` / `tracklabel demo` (`start_viewer` in a background thread)."""

from __future__ import annotations

import time

from annotator_ui.client import ApiClient, ApiError
from annotator_ui.viewer import AnnotatorViewer, ViewerConfig


class ViewerStartError(Exception):
    """The viewer cannot start: the API is unreachable or the token is refused."""


def wait_for_api(api_url: str, timeout_s: float = 30.0) -> None:
    """Poll `<api>/api/v1/health` until it answers 200; ViewerStartError after `timeout_s`."""
    deadline = time.monotonic() + timeout_s
    with ApiClient(api_url, token=None, timeout=2.0) as api:  # the one HTTP client, even for this poll
        while True:
            try:
                api.health()
                return
            except ApiError as exc:
                last = exc.detail if exc.status == 0 else f"HTTP {exc.status}"
            if time.monotonic() >= deadline:
                raise ViewerStartError(f"the track service at {api.base_url} did not answer /api/v1/health ({last})")
            time.sleep(0.25)


def check_token(api_url: str, token: str) -> str:
    """The user name behind `token`; ViewerStartError when the service refuses it."""
    with ApiClient(api_url, token) as api:
        try:
            return str(api.me()["name"])
        except ApiError as exc:
            raise ViewerStartError(f"the token was refused by {api.base_url}: {exc.detail}") from None


def start_viewer(
    api_url: str,
    token: str | None,
    host: str = "127.0.0.1",
    port: int = 8080,
    wait_s: float = 0.0,
    check: bool = True,
    verbose: bool = False,
) -> AnnotatorViewer:
    """Start the viewer's server (it runs in its own threads) and return it. With `check`, the API
    must answer (within `wait_s`) and accept the token first; `serve` and `demo` start the viewer
    before their API is up, so they pass check=False."""
    if check:
        wait_for_api(api_url, wait_s)
        if token:
            check_token(api_url, token)
    return AnnotatorViewer(ViewerConfig(api_url=api_url, token=token or None, host=host, port=port), verbose=verbose)
