"""Migrations upgrade and downgrade on SQLite (and PostgreSQL when configured) and match the models."""

from __future__ import annotations

import uuid

import pytest
from alembic.autogenerate import compare_metadata
from alembic.runtime.migration import MigrationContext
from sqlalchemy import create_engine, inspect, text

from app.core.migrate import downgrade, head_revision, upgrade
from app.models import Base
from tests.app.conftest import PG_URL, pg_schema_url


@pytest.fixture(params=["sqlite", "postgresql"])
def empty_url(request, tmp_path):
    if request.param == "sqlite":
        yield f"sqlite:///{tmp_path / 'mig.db'}"
        return
    if not PG_URL:
        pytest.skip("TRACKLABEL_TEST_DATABASE_URL is not set")
    schema = f"tl_mig_{uuid.uuid4().hex[:10]}"
    admin = create_engine(PG_URL)
    with admin.begin() as conn:
        conn.execute(text(f"CREATE SCHEMA {schema}"))
    yield pg_schema_url(PG_URL, schema)
    with admin.begin() as conn:
        conn.execute(text(f"DROP SCHEMA {schema} CASCADE"))
    admin.dispose()


def _tables(url: str) -> set[str]:
    engine = create_engine(url)
    try:
        return set(inspect(engine).get_table_names()) - {"alembic_version"}
    finally:
        engine.dispose()


def test_migrations_upgrade_creates_every_table(empty_url):
    upgrade(empty_url)
    assert _tables(empty_url) == set(Base.metadata.tables)


def test_migrations_match_models(empty_url):
    upgrade(empty_url)
    engine = create_engine(empty_url)
    with engine.connect() as conn:
        diff = compare_metadata(MigrationContext.configure(conn, opts={"compare_type": True}), Base.metadata)
    engine.dispose()
    assert diff == []


def test_migrations_downgrade_to_base_and_back(empty_url):
    upgrade(empty_url)
    downgrade(empty_url, "base")
    assert _tables(empty_url) == set()
    upgrade(empty_url)
    engine = create_engine(empty_url)
    with engine.connect() as conn:
        assert MigrationContext.configure(conn).get_current_revision() == head_revision(empty_url)
    engine.dispose()


def test_migrations_keep_the_rows_of_rebuilt_tables(empty_url):
    """Rebuilding `tracks` in batch mode (0009, 0010 on SQLite) keeps the rows that point at it:
    with SQLite's foreign keys on, DROP TABLE cascaded and emptied `segments`."""
    upgrade(empty_url, "0008")
    engine = create_engine(empty_url)
    with engine.begin() as conn:
        conn.execute(text("INSERT INTO datasets (id, name, path, created_at) VALUES (1, 'd', '/d', '2026-01-01')"))
        conn.execute(text("INSERT INTO sequences (id, dataset_id, name, path, format, status, n_frames, created_at) "
                          "VALUES (1, 1, 's', '/s', 'kitti', 'ready', 1, '2026-01-01')"))
        conn.execute(text('INSERT INTO frames (id, sequence_id, "index", name, n_points, n_segments, n_samples, artifact) '
                          "VALUES (1, 1, 0, '0', 1, 1, 1, 'a')"))
        conn.execute(text("INSERT INTO tracks (id, sequence_id, key, status, first_frame, last_frame, keep_start, keep_end, "
                          "length, n_samples, n_points, mean_range, version, updated_at) "
                          "VALUES (1, 1, 7, 'pending', 0, 0, 0, 0, 1, 1, 1, 1.0, 1, '2026-01-01')"))
        conn.execute(text("INSERT INTO segments (id, sequence_id, frame_id, frame_index, local_id, track_id, n_points, "
                          "cx, cy, cz, wx, wy, wz, range, valid) VALUES (1, 1, 1, 0, 0, 1, 1, 0, 0, 0, 0, 0, 0, 1.0, true)"))
    engine.dispose()
    upgrade(empty_url)
    engine = create_engine(empty_url)
    with engine.connect() as conn:
        assert conn.execute(text("SELECT count(*) FROM segments")).scalar() == 1
        assert conn.execute(text("SELECT last_track_key FROM sequences")).scalar() == 7  # the counter starts at the top key
    engine.dispose()
