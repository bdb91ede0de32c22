"""Reads queue for a slot while writes go straight through (app/api/read_limit.py)."""

from __future__ import annotations

import asyncio

from app.api.read_limit import ReadLimit


class _App:
    """An ASGI app whose requests block, before answering, until the test releases them; it
    records which paths are computing at once, and can stream a body that waits too."""

    def __init__(self) -> None:
        self.running: set[str] = set()
        self.gates: dict[str, asyncio.Event] = {}
        self.body_gates: dict[str, asyncio.Event] = {}

    def gate(self, path: str) -> asyncio.Event:
        return self.gates.setdefault(path, asyncio.Event())

    async def __call__(self, scope: dict, receive, send) -> None:  # noqa: ANN001
        path = scope["path"]
        self.running.add(path)
        await self.gate(path).wait()
        self.running.discard(path)
        await send({"type": "http.response.start", "status": 200, "headers": []})
        if path in self.body_gates:
            await self.body_gates[path].wait()
        await send({"type": "http.response.body", "body": b"ok"})


def _request(app, method: str, path: str) -> asyncio.Task:  # noqa: ANN001
    async def receive() -> dict:
        return {"type": "http.request", "body": b""}

    async def send(message: dict) -> None:
        pass

    return asyncio.ensure_future(app({"type": "http", "method": method, "path": path}, receive, send))


async def _settle() -> None:
    for _ in range(5):
        await asyncio.sleep(0)


def test_reads_over_the_limit_wait_while_writes_and_exempt_reads_go_through():
    async def scenario() -> None:
        inner = _App()
        app = ReadLimit(inner, limit=2, exempt=("/api/v1/health", "/api/v1/exports"))
        for path in ("/tracks", "/frames/1/payload", "/tracks/2"):
            _request(app, "GET", path)
        write = _request(app, "POST", "/tracks/7/accept")
        health = _request(app, "GET", "/api/v1/health")
        export = _request(app, "GET", "/api/v1/exports/labels")
        await _settle()
        assert inner.running == {"/tracks", "/frames/1/payload", "/tracks/7/accept", "/api/v1/health",
                                 "/api/v1/exports/labels"}
        inner.gate("/tracks/7/accept").set()
        await _settle()
        assert write.done() and not (health.done() or export.done())
        inner.gate("/tracks").set()  # a slot frees: the third read starts
        await _settle()
        assert "/tracks/2" in inner.running

    asyncio.run(scenario())


def test_a_slot_is_given_back_when_the_answer_starts_not_when_its_body_ends():
    async def scenario() -> None:
        inner = _App()
        inner.body_gates["/export"] = asyncio.Event()
        app = ReadLimit(inner, limit=1)
        export = _request(app, "GET", "/export")
        inner.gate("/export").set()  # computed; its streamed body still waits
        await _settle()
        _request(app, "GET", "/tracks")
        await _settle()
        assert "/tracks" in inner.running and not export.done()
        inner.body_gates["/export"].set()
        await _settle()
        assert export.done()

    asyncio.run(scenario())


def test_a_read_that_fails_gives_its_slot_back():
    async def scenario() -> None:
        async def failing(scope, receive, send):  # noqa: ANN001, ANN202
            raise RuntimeError("boom")

        app = ReadLimit(failing, limit=1)
        for _ in range(3):
            task = _request(app, "GET", "/tracks")
            await _settle()
            assert isinstance(task.exception(), RuntimeError)
        assert app._slots is not None and not app._slots.locked()

    asyncio.run(scenario())


def test_the_slots_follow_the_event_loop_that_serves():
    inner = _App()
    app = ReadLimit(inner, limit=1)

    async def two_reads() -> None:
        first, second = _request(app, "GET", "/a"), _request(app, "GET", "/b")
        await _settle()
        assert inner.running == {"/a"}
        inner.gate("/a").set()
        inner.gate("/b").set()
        await asyncio.gather(first, second)
        inner.gates.clear()

    asyncio.run(two_reads())
    asyncio.run(two_reads())  # a new loop: a semaphore of the old one would raise here


def test_the_api_gives_its_reads_the_configured_slots_and_exempts_exports(settings, db):
    from app.main import create_app

    app = create_app(settings.model_copy(update={"read_concurrency": 3}), db=db)
    (limit,) = [m for m in app.user_middleware if m.cls is ReadLimit]
    assert limit.kwargs["limit"] == 3
    assert "/api/v1/exports/semantickitti/1".startswith(limit.kwargs["exempt"])
    assert not "/api/v1/frames/1/payload".startswith(limit.kwargs["exempt"])
