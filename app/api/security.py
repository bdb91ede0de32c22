"""Response headers every answer carries, and the limit on failed sign-ins.

`SecurityHeaders` (outermost ASGI middleware, so that the 413 of `BodyLimit` gets them too):
`X-Content-Type-Options: nosniff`, `X-Frame-Options: DENY`, `Referrer-Policy: no-referrer`, a
Content-Security-Policy that lets a JSON answer load nothing (the docs page loads Swagger UI from
the API's own docs-assets, app/api/docs.py), and `Cache-Control: no-store` unless the route chose its own (a frame payload is
`private, max-age=3600`): an answer that carries a new token is never cached.

`FailedAuthLimit`: a client address that presented `limit` invalid tokens within `window_s`
gets 429 with `Retry-After` until the oldest of them leaves the window, before its token is
looked up. Counted per API process; behind a reverse proxy the address is the client's only
when uvicorn trusts the proxy's `X-Forwarded-For` (`TRACKLABEL_FORWARDED_ALLOW_IPS`).
"""

from __future__ import annotations

import math
import time
from collections import deque
from typing import Any

API_CSP = b"default-src 'none'; frame-ancestors 'none'"
DOCS_CSP = (b"default-src 'none'; script-src 'self' 'unsafe-inline'; style-src 'self' 'unsafe-inline'; "
            b"img-src 'self' data:; connect-src 'self'; frame-ancestors 'none'")
_FIXED = ((b"x-content-type-options", b"nosniff"), (b"x-frame-options", b"DENY"), (b"referrer-policy", b"no-referrer"))


class SecurityHeaders:
    def __init__(self, app: Any, docs_path: str) -> None:
        self.app = app
        self.docs_path = docs_path

    async def __call__(self, scope: dict, receive: Any, send: Any) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        csp = DOCS_CSP if scope.get("path") == self.docs_path else API_CSP

        async def send_with_headers(message: dict) -> None:
            if message["type"] == "http.response.start":
                headers = list(message.get("headers", []))
                names = {k.lower() for k, _ in headers}
                extra = [(k, v) for k, v in (*_FIXED, (b"content-security-policy", csp), (b"cache-control", b"no-store"))
                         if k not in names]
                message = {**message, "headers": headers + extra}
            await send(message)

        await self.app(scope, receive, send_with_headers)


class FailedAuthLimit:
    """Invalid tokens per client address in a sliding window (see the module docstring)."""

    def __init__(self, limit: int, window_s: float = 60.0) -> None:
        self.limit, self.window_s = limit, window_s
        self._failures: dict[str, deque[float]] = {}

    def _recent(self, key: str, now: float) -> deque[float]:
        times = self._failures.get(key, deque())
        while times and times[0] <= now - self.window_s:
            times.popleft()
        return times

    def retry_after(self, key: str) -> int:
        """Whole seconds `key` must wait before its next attempt (0: it may try now)."""
        now = time.monotonic()
        times = self._recent(key, now)
        if len(times) < self.limit:
            return 0
        return max(1, math.ceil(times[0] + self.window_s - now))

    def failed(self, key: str) -> None:
        now = time.monotonic()
        if len(self._failures) > 10_000:  # bounded memory under a spray of addresses
            self._failures = {k: v for k, v in self._failures.items() if self._recent(k, now)}
        times = self._recent(key, now)
        times.append(now)
        self._failures[key] = times
