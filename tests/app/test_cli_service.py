"""The service commands: user add, db upgrade/downgrade, serve (with its worker process)."""

from __future__ import annotations

import os
import socket
import subprocess
import sys
import time
from pathlib import Path

import httpx
import pytest
from sqlalchemy import create_engine, inspect
from typer.testing import CliRunner

from app import crud
from app.cli import app as cli
from app.core.db import Database

REPO = Path(__file__).resolve().parents[2]


@pytest.fixture
def env(tmp_path, monkeypatch):
    monkeypatch.setenv("TRACKLABEL_DATA_DIR", str(tmp_path))
    monkeypatch.delenv("TRACKLABEL_DATABASE_URL", raising=False)
    return {"TRACKLABEL_DATA_DIR": str(tmp_path)}


def test_cli_user_add_prints_a_working_token(env, tmp_path):
    result = CliRunner().invoke(cli, ["user", "add", "alice", "--role", "admin"])
    assert result.exit_code == 0, result.output
    token = result.output.strip()
    db = Database.from_url(f"sqlite:///{tmp_path / 'tracklabel.db'}")
    with db.read() as s:
        user = crud.user_for_token(s, token)
    db.dispose()
    assert user is not None and (user.name, user.role) == ("alice", "admin")


def test_cli_user_add_duplicate_exits_2(env):
    runner = CliRunner()
    assert runner.invoke(cli, ["user", "add", "bob"]).exit_code == 0
    result = runner.invoke(cli, ["user", "add", "bob"])
    assert result.exit_code == 2 and "exists" in result.output


def test_cli_db_upgrade_and_downgrade(env, tmp_path):
    runner = CliRunner()
    assert runner.invoke(cli, ["db", "upgrade"]).exit_code == 0
    engine = create_engine(f"sqlite:///{tmp_path / 'tracklabel.db'}")
    assert "tracks" in inspect(engine).get_table_names()
    assert runner.invoke(cli, ["db", "downgrade", "base"]).exit_code == 0
    assert "tracks" not in inspect(engine).get_table_names()
    engine.dispose()


def _children(pid: int) -> list[str]:
    """Command lines of a process's children (Linux /proc)."""
    path = Path(f"/proc/{pid}/task/{pid}/children")
    kids = path.read_text().split() if path.exists() else []
    return [Path(f"/proc/{k}/cmdline").read_bytes().replace(b"\0", b" ").decode() for k in kids]


def test_cli_serve_runs_the_api_and_a_worker_process(env, tmp_path):
    token = CliRunner().invoke(cli, ["user", "add", "carol"]).output.strip()
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    proc = subprocess.Popen(
        [sys.executable, "-m", "app.cli", "serve", "--port", str(port)],
        cwd=REPO,
        env={**os.environ, **env, "TRACKLABEL_WORKER_POLL_SECONDS": "0.1"},
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    try:
        base = f"http://127.0.0.1:{port}/api/v1"
        headers = {"Authorization": f"Bearer {token}"}
        deadline = time.monotonic() + 60
        while True:
            try:
                if httpx.get(f"{base}/health").status_code == 200:
                    break
            except httpx.HTTPError:
                pass
            assert proc.poll() is None and time.monotonic() < deadline
            time.sleep(0.1)
        job = httpx.post(f"{base}/jobs", json={"type": "selftest"}, headers=headers).json()
        while (state := httpx.get(f"{base}/jobs/{job['id']}", headers=headers).json())["status"] != "succeeded":
            assert state["status"] in ("queued", "running") and time.monotonic() < deadline
            time.sleep(0.1)
        if Path("/proc").is_dir():  # the job ran in a process of its own, not in the API's
            assert any("app.cli worker" in c for c in _children(proc.pid)), _children(proc.pid)
    finally:
        proc.terminate()
        proc.wait(timeout=10)
