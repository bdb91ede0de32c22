"""Two clients act on the same track at the same moment: exactly one wins, the other gets 409."""

from __future__ import annotations

import threading

import httpx


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


def test_concurrency_review_next_never_leases_one_track_twice(live_url, factory):
    factory.ingested_sequence(n_objects=4)
    callers = [factory.user() for _ in range(6)]  # more operators than tracks
    barrier = threading.Barrier(len(callers))
    got: list[int | None] = [None] * len(callers)

    def go(i: int) -> None:
        with httpx.Client(base_url=live_url, timeout=30) as c:
            barrier.wait()
            r = c.post("/api/v1/review/next", headers=callers[i].headers)
            got[i] = r.json()["id"] if r.status_code == 200 else r.status_code

    threads = [threading.Thread(target=go, args=(i,)) for i in range(len(callers))]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    leased = [g for g in got if g != 204]
    assert len(leased) == 4 and len(set(leased)) == 4 and got.count(204) == 2, got
