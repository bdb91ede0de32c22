"""Operators split, merge (both directions at once), undo and accept in one sequence at the same
time, over HTTP against a live server: no response but 200 or 409, and afterwards every track's
event log replays to its state and every frame's artifact agrees with the segment rows.

The storm lasts TRACKLABEL_TEST_STORM_SECONDS (default 5; the issue's acceptance run uses 60):

    TRACKLABEL_TEST_STORM_SECONDS=60 .venv/bin/pytest tests/app/services/test_repair_concurrency.py
"""

from __future__ import annotations

import os
import random
import threading
import time
from collections import Counter

import httpx
import numpy as np
import pytest
from sqlalchemy import func, select

from app import crud
from app.artifacts import ArtifactStore
from app.models import AnnotationEvent, Frame, Segment, Sequence, Track
from tests.app.fakes import fake_pipeline

STORM_SECONDS = float(os.environ.get("TRACKLABEL_TEST_STORM_SECONDS", "5"))
OPERATORS = 6


@pytest.fixture(autouse=True)
def fake_backend():
    with fake_pipeline():
        yield


def _action(c: httpx.Client, rng: random.Random, tracks: list[int], mine: list[int]) -> tuple[str, httpx.Response, int]:
    """One random action with the versions read just before it: often an undo of the operator's
    latest repair (`mine`), so that merged tracks come back and the storm keeps churning; else a
    split, a merge in a random direction or an accept of an ingested track."""
    if mine and rng.random() < 0.4:
        kind, a = "undo", mine[-1]
    else:
        kind = rng.choice(["split", "split", "merge", "merge", "accept"])
        a = rng.choice(tracks)
    va = c.get(f"/api/v1/tracks/{a}").json()["version"]
    if kind == "split":
        angle = rng.uniform(0, 2 * np.pi)
        region = {"kind": "halfspace", "normal": [float(np.cos(angle)), float(np.sin(angle)), 0.0], "offset": 0.0}
        return kind, c.post(f"/api/v1/tracks/{a}/split", json={"version": va, "region": region}), a
    if kind == "merge":  # a random direction: both directions of one pair meet
        b = rng.choice([t for t in tracks if t != a])
        vb = c.get(f"/api/v1/tracks/{b}").json()["version"]
        return kind, c.post(f"/api/v1/tracks/{a}/merge", json={"version": va, "other_track_id": b, "other_version": vb}), a
    return kind, c.post(f"/api/v1/tracks/{a}/{kind}", json={"version": va}), a


def _storm(url: str, callers: list, tracks: list[int], seconds: float) -> tuple[Counter, list[int], list[str]]:
    codes: Counter = Counter()
    new_ids: list[int] = []
    odd: list[str] = []
    lock = threading.Lock()
    deadline = time.monotonic() + seconds

    def operator(i: int) -> None:
        rng, mine = random.Random(i), []
        with httpx.Client(base_url=url, headers=callers[i].headers, timeout=60) as c:
            while time.monotonic() < deadline:
                kind, r, track = _action(c, rng, tracks, mine)
                if r.status_code == 200 and kind in ("split", "merge"):
                    mine.append(track)
                elif kind == "undo" and (r.status_code == 200 or "nothing to undo" in r.text):
                    mine.pop()
                with lock:
                    codes[(kind, r.status_code)] += 1
                    if r.status_code not in (200, 409):
                        odd.append(f"{kind}: {r.status_code} {r.text[:300]}")
                    elif kind == "split" and r.status_code == 200:
                        new_ids.append(r.json()["new_track"]["id"])

    threads = [threading.Thread(target=operator, args=(i,)) for i in range(len(callers))]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    return codes, new_ids, odd


def _check_frames(factory, settings, seq: int) -> None:
    """Each frame's per-point segment and track ids, and its samples, agree with its segment rows."""
    store = ArtifactStore(settings.artifacts_path)
    with factory.db.read() as s:
        for frame in s.scalars(select(Frame).where(Frame.sequence_id == seq)).all():
            art = store.read_frame(frame.artifact)
            rows = s.execute(select(Segment.local_id, Segment.track_id, Segment.n_points, Segment.sample_index)
                             .where(Segment.frame_id == frame.id)).all()
            for local, track_id, n_points, sample_index in rows:
                mine = art.segment == local
                assert int(mine.sum()) == n_points, (frame.index, local)
                assert set(art.track[mine].tolist()) <= {track_id or 0}, (frame.index, local, track_id)
                assert sample_index is None or art.sample_segment[sample_index] == local, (frame.index, local)
            assert len(art.samples) == frame.n_samples == sum(r.sample_index is not None for r in rows)
            assert set(np.unique(art.segment[art.segment >= 0]).tolist()) <= {r.local_id for r in rows}


def _check_tracks(factory, seq: int) -> None:
    """Every track's log replays to its state; its version counts its events; keys are below the counter."""
    with factory.db.read() as s:
        last_key = s.scalar(select(Sequence.last_track_key).where(Sequence.id == seq))
        for track in s.scalars(select(Track).where(Track.sequence_id == seq)).all():
            assert crud.rebuild_review_state(s, track) == crud.review_state(track)
            events = s.scalar(select(func.count()).where(AnnotationEvent.track_id == track.id))
            assert track.version == 1 + events, (track.id, track.version, events)
            assert track.key <= last_key


def test_repair_concurrency_storm_only_200_or_409_and_consistent(live_url, factory, settings):
    seq = factory.ingested_sequence(n_frames=6, n_objects=6)
    callers = [factory.user() for _ in range(OPERATORS)]
    tracks = factory.track_ids(seq)
    codes, new_ids, odd = _storm(live_url, callers, tracks, STORM_SECONDS)
    print(f"storm {STORM_SECONDS:g} s, {factory.db.dialect}: {sorted(codes.items())}")  # quoted in docs/service.md
    assert not odd, odd[:5]
    for kind in ("split", "merge"):
        assert codes[(kind, 200)] > 0, codes  # the storm did change tracks, not only refuse
    assert len(new_ids) == len(set(new_ids))  # a split's new track id is never given twice
    _check_tracks(factory, seq)
    _check_frames(factory, settings, seq)


def _together(url: str, calls: list[tuple]) -> list[httpx.Response]:
    """Send each (caller, path, body) from its own thread at the same moment."""
    barrier = threading.Barrier(len(calls))
    out: list = [None] * len(calls)

    def go(i: int, caller, path: str, body: dict) -> None:
        with httpx.Client(base_url=url, headers=caller.headers, timeout=60) as c:
            barrier.wait()
            out[i] = c.post(path, json=body)

    threads = [threading.Thread(target=go, args=(i, *call)) for i, call in enumerate(calls)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    return out


def test_repair_concurrency_two_splits_of_one_sequence_both_succeed(live_url, factory):
    """Two operators split two tracks seen in the same frames at once: both get their split, with
    distinct new keys (max(key)+1 without a lock gave one of them 500)."""
    seq = factory.ingested_sequence(n_frames=4, n_objects=2)
    a, b = factory.track_ids(seq)
    ops = [factory.user(), factory.user()]
    for round_, normal in enumerate(([1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0])):
        half = {"kind": "halfspace", "normal": normal, "offset": 0.0}  # a new half of what is left
        va, vb = factory.track(a).version, factory.track(b).version
        r = _together(live_url, [(ops[0], f"/api/v1/tracks/{a}/split", {"version": va, "region": half}),
                                 (ops[1], f"/api/v1/tracks/{b}/split", {"version": vb, "region": half})])
        assert [x.status_code for x in r] == [200, 200], [x.text for x in r]
        keys = {x.json()["new_track"]["key"] for x in r}
        assert len(keys) == 2, (round_, keys)
    _check_tracks(factory, seq)


def test_repair_concurrency_merges_in_opposite_directions_one_wins(live_url, factory, settings):
    """Op 1 merges X <- Y while op 2 merges Y <- X: one 200, one 409, never a deadlock's 500."""
    seq = factory.ingested_sequence(n_frames=4, n_objects=2)
    x, y = factory.track_ids(seq)
    ops = [factory.user(), factory.user()]
    for _ in range(5):
        vx, vy = factory.track(x).version, factory.track(y).version
        r = _together(live_url, [
            (ops[0], f"/api/v1/tracks/{x}/merge", {"version": vx, "other_track_id": y, "other_version": vy}),
            (ops[1], f"/api/v1/tracks/{y}/merge", {"version": vy, "other_track_id": x, "other_version": vx}),
        ])
        assert sorted(z.status_code for z in r) == [200, 409], [z.text for z in r]
        winner = 0 if r[0].status_code == 200 else 1
        target = (x, y)[winner]
        with httpx.Client(base_url=live_url, headers=ops[winner].headers) as c:
            assert c.post(f"/api/v1/tracks/{target}/undo", json={"version": factory.track(target).version}).status_code == 200
    _check_tracks(factory, seq)
    _check_frames(factory, settings, seq)
