"""ASGI middleware: at most `limit` reads compute their answers at once; writes never wait.

One API process runs every sync route on one GIL, so requests in flight share one core. Under
load a write (an accept, `review/next`) that shares it with many reads (track pages, frame
payloads) takes several times its own cost, and on SQLite it holds the database's write lock all
that time, so every other operator's write waits too. Reads therefore queue here for a slot, in
the event loop where waiting costs nothing, and writes go straight through.

A slot covers computing the answer, not sending it: it is given back at the response's start, so
a slow client never holds one. Paths under `exempt` never wait: health checks, and exports, which
can compute for minutes before their first byte and would stop every viewer's reads meanwhile.
"""

from __future__ import annotations

import asyncio
from typing import Any

_READS = frozenset({"GET", "HEAD"})


class ReadLimit:
    def __init__(self, app: Any, limit: int, exempt: tuple[str, ...] = ()) -> None:
        self.app = app
        self.limit = limit
        self.exempt = exempt
        self._slots: asyncio.Semaphore | None = None
        self._loop: asyncio.AbstractEventLoop | None = None

    async def __call__(self, scope: dict, receive: Any, send: Any) -> None:
        if scope["type"] != "http" or scope["method"] not in _READS or scope["path"].startswith(self.exempt):
            await self.app(scope, receive, send)
            return
        slots = self._slots_of(asyncio.get_running_loop())
        await slots.acquire()
        held = True

        async def releasing_send(message: dict) -> None:
            nonlocal held
            if held and message["type"] == "http.response.start":
                held = False
                slots.release()
            await send(message)

        try:
            await self.app(scope, receive, releasing_send)
        finally:
            if held:
                slots.release()

    def _slots_of(self, loop: asyncio.AbstractEventLoop) -> asyncio.Semaphore:
        """The slots, made in the loop that serves (a semaphore belongs to one event loop, and a
        test client runs each of its sessions in a new one)."""
        if self._slots is None or self._loop is not loop:
            self._slots, self._loop = asyncio.Semaphore(self.limit), loop
        return self._slots
