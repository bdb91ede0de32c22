"""Fresh ids and keys for the tracks a split creates.

A track's `key` is its id within the sequence (the pipeline's track id, and the instance id of
the SemanticKITTI export). A split's new track takes the next key from its sequence's counter
row (`sequences.last_track_key`), incremented under that row's lock, so two splits at once never
take the same key (`max(key) + 1` did: the loser hit `uq_tracks_sequence_id_key`), and a key
handed out once is never handed out again, even when an undo removes the track that had it.
The counter never falls below the sequence's highest key, whoever inserted the tracks.

Its database `id` is reserved the same way, from the id sequence of the tracks table (SQLite:
AUTOINCREMENT's `sqlite_sequence` row), before the split does its slow part: the split writes
the new id into the frames' artifact files outside its write transaction. Reserved and unused
(the split failed) leaves a gap; an id is never given twice either.
"""

from __future__ import annotations

from dataclasses import dataclass

from sqlalchemy import text
from sqlalchemy.orm import Session

from app.core.db import Database

_NEXT_KEY = text(
    "UPDATE sequences SET last_track_key = 1 + CASE WHEN last_track_key >= k.top THEN last_track_key ELSE k.top END "
    "FROM (SELECT COALESCE(MAX(key), 0) AS top FROM tracks WHERE sequence_id = :sid) AS k "
    "WHERE sequences.id = :sid RETURNING last_track_key"
)
_NEXT_KEY_SQLITE = text(
    "UPDATE sequences SET last_track_key = 1 + MAX(last_track_key, "
    "(SELECT COALESCE(MAX(key), 0) FROM tracks WHERE sequence_id = :sid)) WHERE id = :sid RETURNING last_track_key"
)
_SEED_SQLITE_ID = text(
    "INSERT INTO sqlite_sequence (name, seq) SELECT 'tracks', COALESCE((SELECT MAX(id) FROM tracks), 0) "
    "WHERE NOT EXISTS (SELECT 1 FROM sqlite_sequence WHERE name = 'tracks')"
)
_NEXT_ID_SQLITE = text(
    "UPDATE sqlite_sequence SET seq = 1 + MAX(seq, COALESCE((SELECT MAX(id) FROM tracks), 0)) "
    "WHERE name = 'tracks' RETURNING seq"
)
_NEXT_ID_PG = text("SELECT nextval(pg_get_serial_sequence('tracks', 'id'))")


@dataclass(frozen=True)
class TrackIds:
    id: int
    key: int


def next_key(session: Session, sequence_id: int) -> int:
    """The sequence's next track key (locks its row until the transaction ends)."""
    sql = _NEXT_KEY_SQLITE if session.get_bind().dialect.name == "sqlite" else _NEXT_KEY
    key = session.execute(sql, {"sid": sequence_id}).scalar()
    if key is None:
        raise LookupError(f"sequence {sequence_id} not found")
    return int(key)


def next_track_id(session: Session) -> int:
    """A tracks.id that no row has and none will get."""
    if session.get_bind().dialect.name == "sqlite":
        session.execute(_SEED_SQLITE_ID)
        return int(session.execute(_NEXT_ID_SQLITE).scalar_one())
    return int(session.execute(_NEXT_ID_PG).scalar_one())


def reserve(db: Database, sequence_id: int) -> TrackIds:
    """A fresh (id, key) for a new track of the sequence, in its own short transaction."""
    with db.write() as session:
        ids = TrackIds(id=next_track_id(session), key=next_key(session, sequence_id))
        session.commit()
    return ids
