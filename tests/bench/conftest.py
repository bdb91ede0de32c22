"""The service fixtures (a database per test, users, fake ingests) for the benchmark tests."""

from tests.app.conftest import client, db, db_kind, db_url, factory, pg_schema, settings  # noqa: F401
