"""Settings, the SQLite engine's pragmas, and artifact files."""

from __future__ import annotations

import io
import os
from pathlib import Path

import numpy as np
from sqlalchemy import func, select, text

from app.artifacts import ArtifactStore, FrameArtifact
from app.core.config import Settings
from app.core.db import Database
from app.models import User


def test_config_defaults_live_under_data_dir(tmp_path, monkeypatch):
    for key in list(os.environ):
        if key.startswith("TRACKLABEL_"):
            monkeypatch.delenv(key)
    s = Settings(data_dir=tmp_path)
    assert s.db_url == f"sqlite:///{tmp_path.as_posix()}/tracklabel.db"
    assert s.artifacts_path == tmp_path / "artifacts" and s.data_roots == [tmp_path]


def test_config_data_roots_split_from_env(monkeypatch):
    monkeypatch.setenv("TRACKLABEL_DATA_ROOTS", f"/a{os.pathsep}/b,/c")
    assert Settings().data_roots == [Path("/a"), Path("/b"), Path("/c")]


def test_db_sqlite_runs_wal_with_foreign_keys(tmp_path):
    db = Database.from_url(f"sqlite:///{tmp_path / 'x.db'}")
    with db.read() as s:
        mode = s.execute(text("PRAGMA journal_mode")).scalar()
        fk = s.execute(text("PRAGMA foreign_keys")).scalar()
        busy = s.execute(text("PRAGMA busy_timeout")).scalar()
    db.dispose()
    assert (mode, fk) == ("wal", 1) and busy > 0


def test_db_read_sessions_hold_no_transaction_on_postgresql(db, factory):
    """PostgreSQL read sessions run in autocommit: no BEGIN / ROLLBACK round trips, no transaction
    left open between statements, and each statement sees the latest commits. SQLite's deferred
    read transaction keeps one snapshot."""
    with db.read() as r:
        before = r.scalar(select(func.count()).select_from(User))
        factory.user()
        after = r.scalar(select(func.count()).select_from(User))
        if db.dialect == "postgresql":
            pid = r.scalar(text("SELECT pg_backend_pid()"))
            with db.engine.connect() as c:
                state = c.scalar(text("SELECT state FROM pg_stat_activity WHERE pid = :pid"), {"pid": pid})
            assert (after, state) == (before + 1, "idle")
        else:
            assert after == before


def _frame(n: int, value: float) -> FrameArtifact:
    seg = np.repeat(np.arange(-1, n // 10 - 1, dtype=np.int32), 10)[:n]
    return FrameArtifact(
        points=np.full((n, 3), value, np.float32),
        intensity=np.zeros(n, np.float32),
        segment=seg,
        ground=seg < 0,
        track=np.where(seg >= 0, seg + 100, 0).astype(np.int64),
        samples=np.zeros((2, 4, 8, 8), np.uint8),
        sample_segment=np.arange(2, dtype=np.int32),
    )


def test_artifacts_round_trip(tmp_path):
    store = ArtifactStore(tmp_path)
    rel = store.write_frame(3, 7, _frame(50, 1.5))
    back = store.read_frame(rel)
    assert rel == "seq_000003/000007.npz" and np.array_equal(back.track, _frame(50, 1.5).track)


def test_artifacts_payload_cache_sees_a_rewritten_frame(tmp_path):
    store = ArtifactStore(tmp_path, payload_cache_bytes=1 << 20)
    rel = store.write_frame(1, 0, _frame(40, 1.0))
    first = np.load(io.BytesIO(store.payload(rel)))["points"][0, 0]
    os.utime(store.path(rel), ns=(0, 0))  # make sure the rewrite below changes the mtime
    store.write_frame(1, 0, _frame(40, 2.0))
    second = np.load(io.BytesIO(store.payload(rel)))["points"][0, 0]
    assert (first, second) == (1.0, 2.0)
