"""A route whose transaction loses a race runs again (app/api/retry.py): the caller gets the
answer of the run that won, or a 409 after ATTEMPTS losses; never a 500."""

from __future__ import annotations

import sqlite3

from sqlalchemy.exc import OperationalError

from app import crud
from app.api import retry


def _failing_first(monkeypatch, times: int) -> list[int]:
    calls = [0]
    real = crud.apply_action

    def flaky(*args, **kwargs):
        calls[0] += 1
        if calls[0] <= times:
            raise OperationalError("UPDATE tracks ...", {}, sqlite3.OperationalError("database is locked"))
        return real(*args, **kwargs)

    monkeypatch.setattr(crud, "apply_action", flaky)
    return calls


def test_retry_a_lost_race_runs_the_route_again(client, factory, monkeypatch):
    seq = factory.ingested_sequence(n_frames=3, n_objects=1)
    op = factory.user()
    calls = _failing_first(monkeypatch, 2)
    r = client.post(f"/api/v1/tracks/{factory.track_ids(seq)[0]}/accept", json={"version": 1}, headers=op.headers)
    assert r.status_code == 200 and r.json()["version"] == 2 and calls[0] == 3


def test_retry_too_many_losses_is_409_not_500(client, factory, monkeypatch):
    seq = factory.ingested_sequence(n_frames=3, n_objects=1)
    op = factory.user()
    calls = _failing_first(monkeypatch, 100)
    r = client.post(f"/api/v1/tracks/{factory.track_ids(seq)[0]}/accept", json={"version": 1}, headers=op.headers)
    assert r.status_code == 409 and isinstance(r.json()["detail"], str) and calls[0] == retry.ATTEMPTS
    assert factory.track(factory.track_ids(seq)[0]).version == 1
