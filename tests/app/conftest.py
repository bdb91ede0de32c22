"""Fixtures of the service tests: one database per test, on SQLite always and on PostgreSQL when
TRACKLABEL_TEST_DATABASE_URL is set (a fresh schema per test session, tables truncated per test).

Tests build their schema with `create_all` (migrations are tested on their own in test_migrations).
"""

from __future__ import annotations

import os
import socket
import threading
import time
import uuid
from collections.abc import Iterator
from pathlib import Path

import pytest
import uvicorn
from fastapi.testclient import TestClient
from sqlalchemy import create_engine, text

from app.core.config import Settings
from app.core.db import Database
from app.main import create_app
from app.models import Base
from tests.app.factories import Factory

PG_URL = os.environ.get("TRACKLABEL_TEST_DATABASE_URL")
# Every service test runs on both databases; without a PostgreSQL URL its PostgreSQL run shows
# as skipped (with the reason) instead of vanishing from the count.
DB_KINDS = [
    "sqlite",
    pytest.param("postgresql", marks=[pytest.mark.postgres, pytest.mark.skipif(
        not PG_URL, reason="PostgreSQL: TRACKLABEL_TEST_DATABASE_URL is not set")]),
]


def pg_schema_url(base: str, schema: str) -> str:
    sep = "&" if "?" in base else "?"
    return f"{base}{sep}options=-csearch_path%3D{schema}"


@pytest.fixture(scope="session", params=DB_KINDS)
def db_kind(request: pytest.FixtureRequest) -> Iterator[str]:
    yield request.param


@pytest.fixture(scope="session")
def pg_schema() -> Iterator[str | None]:
    """A fresh PostgreSQL schema with the tables, for the whole session (None without PostgreSQL)."""
    if not PG_URL:
        yield None
        return
    schema = f"tl_test_{uuid.uuid4().hex[:10]}"
    admin = create_engine(PG_URL)
    with admin.begin() as conn:
        conn.execute(text(f"CREATE SCHEMA {schema}"))
    engine = create_engine(pg_schema_url(PG_URL, schema))
    Base.metadata.create_all(engine)
    engine.dispose()
    yield schema
    with admin.begin() as conn:
        conn.execute(text(f"DROP SCHEMA {schema} CASCADE"))
    admin.dispose()


@pytest.fixture
def db_url(db_kind: str, tmp_path: Path, request: pytest.FixtureRequest) -> str:
    if db_kind == "sqlite":
        url = f"sqlite:///{tmp_path / 'test.db'}"
        engine = create_engine(url)
        Base.metadata.create_all(engine)
        engine.dispose()
        return url
    return emptied_pg_url(request.getfixturevalue("pg_schema"))


def emptied_pg_url(schema: str | None) -> str:
    """The URL of the session's PostgreSQL schema, its tables emptied."""
    assert PG_URL and schema
    url = pg_schema_url(PG_URL, schema)
    engine = create_engine(url)
    names = ", ".join(t.name for t in Base.metadata.sorted_tables)
    with engine.begin() as conn:
        conn.execute(text(f"TRUNCATE {names} RESTART IDENTITY CASCADE"))
    engine.dispose()
    return url


@pytest.fixture
def settings(db_url: str, tmp_path: Path) -> Settings:
    roots = tmp_path / "roots"
    roots.mkdir(exist_ok=True)
    return Settings(
        data_dir=tmp_path,
        database_url=db_url,
        data_roots=[roots],
        embedded_worker=False,
        job_lease_seconds=30.0,
        job_heartbeat_seconds=0.2,
        worker_poll_seconds=0.05,
        ingest_batch_frames=3,
    )


@pytest.fixture
def db(settings: Settings) -> Iterator[Database]:
    database = Database.from_settings(settings)
    yield database
    database.dispose()


@pytest.fixture
def factory(db: Database, settings: Settings) -> Factory:
    return Factory(db, settings)


@pytest.fixture
def client(settings: Settings, db: Database) -> Iterator[TestClient]:
    with TestClient(create_app(settings, db=db)) as c:
        yield c


@pytest.fixture
def live_url(settings: Settings, db: Database) -> Iterator[str]:
    """The app served by uvicorn on a free loopback port (a thread of this process)."""
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
