"""A route whose transaction loses a race runs again (app/api/retry.py): the caller gets the
answer of the run that won, or a 409 after ATTEMPTS losses; never a 500."""

from __future__ import annotations

import sqlite3

import pytest
from fastapi.testclient import TestClient
from sqlalchemy import create_engine, text
from sqlalchemy.exc import OperationalError

from app import crud
from app.api import retry
from app.core.config import Settings
from app.core.db import Database
from app.main import create_app
from tests.app.conftest import PG_URL, emptied_pg_url
from tests.app.factories import Factory


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


def _pooled_pids(engine, k: int = 3) -> list[int]:  # noqa: ANN001
    """The backend pids of (at least) every connection in `engine`'s pool."""
    conns = [engine.connect() for _ in range(k)]
    pids = [c.scalar(text("SELECT pg_backend_pid()")) for c in conns]
    for c in conns:
        c.close()
    return pids


def _drop(pids: list[int]) -> None:
    admin = create_engine(PG_URL)
    with admin.connect() as conn:
        for pid in pids:
            conn.execute(text("SELECT pg_terminate_backend(:pid)"), {"pid": pid})
        conn.commit()
    admin.dispose()


@pytest.mark.postgres
@pytest.mark.skipif(not PG_URL, reason="PostgreSQL: TRACKLABEL_TEST_DATABASE_URL is not set")
def test_requests_succeed_after_postgresql_dropped_the_apis_pooled_connections(pg_schema, tmp_path):
    """The API does not ping a pooled connection before each use (a round trip per request): a
    connection the database dropped (a restart) fails once, and the request runs again."""
    settings = Settings(data_dir=tmp_path, database_url=emptied_pg_url(pg_schema),
                        data_roots=[tmp_path], embedded_worker=False)
    db = Database.from_settings(settings)
    factory = Factory(db, settings)
    seq = factory.ingested_sequence(n_frames=3, n_objects=1)
    op = factory.user()
    track = factory.track_ids(seq)[0]
    with TestClient(create_app(settings)) as client:
        engine = client.app.state.db.engine
        assert client.get("/api/v1/users/me", headers=op.headers).status_code == 200
        _drop(_pooled_pids(engine))
        assert client.get(f"/api/v1/tracks/{track}", headers=op.headers).status_code == 200
        _drop(_pooled_pids(engine))
        r = client.post(f"/api/v1/tracks/{track}/accept", json={"version": 1}, headers=op.headers)
        assert r.status_code == 200 and r.json()["version"] == 2
    db.dispose()
