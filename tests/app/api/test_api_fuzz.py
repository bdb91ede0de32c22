"""The API contract (issue 23): schemathesis with all its checks, not only "no 5xx", finds no
failure on any operation, as an admin and as an operator (SQLite, and PostgreSQL when
TRACKLABEL_TEST_DATABASE_URL is set). Kept
short (a few derandomised examples per operation and mode); `bench/bench_service.py` runs the
same check with many more."""

from __future__ import annotations

import pytest

from tests.app.contract import run_contract

EXAMPLES_PER_OPERATION = 6


@pytest.mark.parametrize("role", ["admin", "operator"])
def test_api_fuzz_contract_holds(client, factory, role):
    report = run_contract(client, factory, EXAMPLES_PER_OPERATION, role)
    assert report["operations"] >= 25 and report["negated"] >= report["operations"] - 5
    assert not report["failure_list"], "\n\n".join(report["failure_list"])
