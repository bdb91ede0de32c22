"""Engine and sessions.

SQLite (the embedded default) runs in WAL mode with foreign keys on and a busy timeout. pysqlite's
own transaction handling is switched off and we emit `BEGIN` ourselves, so that write sessions can
open with `BEGIN IMMEDIATE`: a deferred transaction that reads first and writes later fails with
SQLITE_BUSY (no wait) when another writer committed in between; an immediate one queues instead.
PostgreSQL uses ordinary transactions for writers, which lock rows (`FOR UPDATE [SKIP LOCKED]`)
where needed; its read sessions run in autocommit (each statement sees the latest commits, as in a
READ COMMITTED transaction, without the BEGIN and ROLLBACK round trips).
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass
from pathlib import Path

from sqlalchemy import Connection, Engine, create_engine, event, text
from sqlalchemy.engine import make_url
from sqlalchemy.orm import Session, sessionmaker

from app.core.config import Settings

SQLITE_BUSY_TIMEOUT_MS = 30_000


def _install_sqlite_hooks(engine: Engine) -> None:
    @event.listens_for(engine, "connect")
    def _on_connect(dbapi_conn, _record) -> None:  # noqa: ANN001
        dbapi_conn.isolation_level = None  # we issue BEGIN ourselves (see module docstring)
        cur = dbapi_conn.cursor()
        cur.execute("PRAGMA journal_mode=WAL")
        cur.execute("PRAGMA foreign_keys=ON")
        cur.execute(f"PRAGMA busy_timeout={SQLITE_BUSY_TIMEOUT_MS}")
        cur.execute("PRAGMA synchronous=NORMAL")
        cur.close()

    # Writers of this process queue on a lock before BEGIN IMMEDIATE: SQLite's busy handler retries
    # with sleeps of up to 100 ms, which under many concurrent writers gives second-long tails; a
    # lock hands over at once. (Other processes, e.g. a worker, still meet the busy handler.)
    write_lock = threading.Lock()

    def _release(conn) -> None:  # noqa: ANN001
        if conn.info.pop("tracklabel_write_lock", False):
            write_lock.release()

    @event.listens_for(engine, "begin")
    def _on_begin(conn) -> None:  # noqa: ANN001
        immediate = bool(conn.get_execution_options().get("sqlite_immediate"))
        if immediate and not conn.info.get("tracklabel_write_lock"):
            if not write_lock.acquire(timeout=SQLITE_BUSY_TIMEOUT_MS / 1000):
                raise TimeoutError("timed out waiting for the database write lock")
            conn.info["tracklabel_write_lock"] = True
        try:
            conn.exec_driver_sql(f"BEGIN {'IMMEDIATE' if immediate else 'DEFERRED'}")
        except BaseException:
            _release(conn)
            raise

    event.listen(engine, "commit", _release)
    event.listen(engine, "rollback", _release)

    @event.listens_for(engine, "checkin")
    def _on_checkin(_dbapi_conn, record) -> None:  # noqa: ANN001
        if record.info.pop("tracklabel_write_lock", False):
            write_lock.release()


def make_engine(url: str, echo: bool = False, pre_ping: bool = True) -> Engine:
    """An engine for `url`; SQLite files get their folder created and the pragmas above.
    `pre_ping` tests a pooled PostgreSQL connection with a round trip before each use."""
    u = make_url(url)
    if u.get_backend_name() == "sqlite":
        if u.database and u.database != ":memory:":
            Path(u.database).parent.mkdir(parents=True, exist_ok=True)
        engine = create_engine(url, echo=echo, connect_args={"check_same_thread": False, "timeout": 30})
        _install_sqlite_hooks(engine)
        return engine
    return create_engine(url, echo=echo, pool_pre_ping=pre_ping, pool_size=10, max_overflow=20)


@dataclass
class Database:
    """An engine with a read session factory and a write session factory.

    `read()` sessions begin deferred on SQLite and run in autocommit on PostgreSQL; they never
    write. `write()` sessions begin IMMEDIATE on SQLite, so the whole transaction holds the write
    lock and never fails on a stale snapshot.
    """

    engine: Engine
    read: sessionmaker[Session]
    write: sessionmaker[Session]

    @classmethod
    def from_url(cls, url: str, pre_ping: bool = True) -> Database:
        engine = make_engine(url, pre_ping=pre_ping)
        writer = engine.execution_options(sqlite_immediate=True)
        # PostgreSQL's READ COMMITTED gives each statement its own snapshot anyway, so a read
        # session's BEGIN and ROLLBACK would only add two round trips to every request
        reader = engine if engine.dialect.name == "sqlite" else engine.execution_options(isolation_level="AUTOCOMMIT")
        return cls(
            engine=engine,
            read=sessionmaker(reader, expire_on_commit=False),
            write=sessionmaker(writer, expire_on_commit=False),
        )

    @classmethod
    def from_settings(cls, settings: Settings, pre_ping: bool = True) -> Database:
        return cls.from_url(settings.db_url, pre_ping)

    def connect_read(self) -> Connection:
        """A Core connection that reads as `read()` sessions do (autocommit on PostgreSQL)."""
        return self.read.kw["bind"].connect()

    @property
    def dialect(self) -> str:
        return self.engine.dialect.name

    def ping(self) -> None:
        """Raise unless the database answers `SELECT 1`."""
        ping(self.engine)

    def dispose(self) -> None:
        self.engine.dispose()


def ping(engine: Engine) -> None:
    """Raise unless the database answers `SELECT 1`."""
    with engine.connect() as conn:
        conn.execute(text("SELECT 1"))


def wait_for_db(engine: Engine, timeout_s: float = 60.0, interval_s: float = 1.0) -> None:
    """Block until `SELECT 1` succeeds (start-up order: wait for the DB, upgrade, seed)."""
    deadline = time.monotonic() + timeout_s
    while True:
        try:
            ping(engine)
            return
        except Exception:
            if time.monotonic() >= deadline:
                raise
            time.sleep(interval_s)


# PostgreSQL SQLSTATEs of a transaction that lost a race and may simply run again: serialization
# failure, deadlock, and the unique / foreign-key violations of two writers inserting the same
# row at once (run again, the loser finds the winner's row and answers 404 / 409 itself)
_RETRY_SQLSTATES = frozenset({"40001", "40P01", "23505", "23503"})
_RETRY_SQLITE = ("database is locked", "database table is locked", "UNIQUE constraint failed",
                 "FOREIGN KEY constraint failed")


def is_transient(exc: BaseException) -> bool:
    """True for an error that says another transaction got there first (a deadlock, a
    serialization failure, a lock wait that ran out, a duplicate insert of a racing writer):
    the request may run again from the start. So may one whose pooled connection the database
    dropped (a restart): SQLAlchemy then renews the whole pool."""
    from sqlalchemy.exc import DBAPIError

    if isinstance(exc, TimeoutError):  # this process's SQLite write lock (see _on_begin)
        return True
    if not isinstance(exc, DBAPIError):
        return False
    if exc.connection_invalidated:  # the database dropped a pooled connection: the pool is renewed
        return True
    code = getattr(exc.orig, "sqlstate", None)
    if code is not None:
        return code in _RETRY_SQLSTATES
    return any(text in str(exc.orig) for text in _RETRY_SQLITE)
