"""Two clients act on the same track at the same moment: exactly one wins, the other gets 409."""

from __future__ import annotations

import socket
import threading
import time

import httpx
import pytest
import uvicorn

from app.main import create_app


@pytest.fixture
def live_url(settings, db):
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    server = uvicorn.Server(uvicorn.Config(create_app(settings, db=db), host="127.0.0.1", port=port, log_level="warning"))
    t = threading.Thread(target=server.run, daemon=True)
    t.start()
    deadline = time.monotonic() + 10
    while not server.started:
        assert time.monotonic() < deadline
        time.sleep(0.02)
    yield f"http://127.0.0.1:{port}"
    server.should_exit = True
    t.join(timeout=5)


def _race(url, track_id, bodies):
    barrier = threading.Barrier(len(bodies))
    results = [None] * len(bodies)

    def go(i, action, json, headers):
        with httpx.Client(base_url=url, timeout=30) as c:
            barrier.wait()
            results[i] = c.post(f"/api/v1/tracks/{track_id}/{action}", json=json, headers=headers).status_code

    threads = [threading.Thread(target=go, args=(i, *b)) for i, b in enumerate(bodies)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    return results


def test_concurrency_same_track_one_wins_other_409(live_url, factory):
    seq = factory.ingested_sequence(n_objects=5)
    a, b = factory.user(), factory.user()
    for track_id in factory.track_ids(seq):
        codes = _race(
            live_url,
            track_id,
            [("accept", {"version": 1}, a.headers), ("discard", {"version": 1}, b.headers)],
        )
        assert sorted(codes) == [200, 409]
        assert factory.track(track_id).version == 2
