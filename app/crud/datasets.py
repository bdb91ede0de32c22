"""Datasets and sequences: registration under the data roots, statistics, the ready check."""

from __future__ import annotations

import os
from pathlib import Path, PurePath
from typing import Any

from sqlalchemy import bindparam, func, select
from sqlalchemy.orm import Session

from app.core.errors import Conflict, Forbidden, Invalid, NotFound
from app.models import Dataset, Frame, PairConstraint, Sequence, Track


def resolve_registration_path(raw: str, roots: list[Path]) -> Path:
    """The real path of `raw` if it lies under one of `roots`.

    `..` anywhere, or a (symlink-resolved) path outside every root -> Forbidden (403);
    a path under a root that does not exist -> NotFound. Relative paths are tried against each root.
    """
    if "\x00" in raw:
        raise Invalid("path contains a NUL byte")
    pure = PurePath(raw)
    if ".." in pure.parts:
        raise Forbidden("paths with '..' are refused")
    real_roots = [r.resolve() for r in roots]
    candidates = [Path(pure)] if pure.is_absolute() else [r / pure for r in real_roots]
    inside = False
    for cand in candidates:
        try:
            real = cand.resolve()
        except (OSError, RuntimeError, ValueError) as exc:
            raise Invalid(f"cannot resolve path: {exc}") from exc
        if any(real == r or real.is_relative_to(r) for r in real_roots):
            inside = True
            if real.exists():
                return real
    if not inside:
        raise Forbidden("path is outside the configured data roots")
    raise NotFound(f"no such file or folder under the data roots: {raw}")


def check_tree_inside_roots(path: Path, roots: list[Path]) -> None:
    """Forbidden (403) naming the first file or folder under `path` (or `path` itself) whose real
    path (symlinks resolved) lies outside every root: a link inside a root must not smuggle in a
    file from elsewhere. Checked at registration and again when ingest opens the sequence."""
    real_roots = [r.resolve() for r in roots]

    def inside(p: Path) -> bool:
        real = p.resolve()
        return any(real == r or real.is_relative_to(r) for r in real_roots)

    if not inside(path):
        raise Forbidden(f"{path.name} resolves outside the configured data roots")
    if not path.is_dir():
        return
    for folder, dirs, files in os.walk(path, followlinks=False):
        for name in (*dirs, *files):
            entry = Path(folder) / name
            if entry.is_symlink() and not inside(entry):
                raise Forbidden(
                    f"{entry.relative_to(path)} is a link to outside the configured data roots; refused"
                )


def registered_sequence_id(session: Session, path: Path) -> int | None:
    """The id of a sequence already registered at `path` (resolved), if any."""
    return session.scalar(select(Sequence.id).where(Sequence.path == str(path)).order_by(Sequence.id).limit(1))


def create_dataset(
    session: Session,
    path: Path,
    name: str | None,
    fmt: str,
    config: dict[str, Any] | None,
    user_id: int,
) -> tuple[Dataset, Sequence]:
    """Register one sequence path (already resolved and checked). Flushes, does not commit."""
    ds = Dataset(name=name or path.name, path=str(path), created_by_id=user_id)
    session.add(ds)
    session.flush()
    seq = Sequence(dataset_id=ds.id, name=name or path.name, path=str(path), format=fmt, config=config)
    session.add(seq)
    session.flush()
    return ds, seq


def sequence_stats(session: Session, seq: Sequence) -> dict[str, Any]:
    by_status = dict(
        session.execute(
            select(Track.status, func.count()).where(Track.sequence_id == seq.id).group_by(Track.status)
        ).all()
    )
    frames, segments, samples = session.execute(
        select(func.count(), func.coalesce(func.sum(Frame.n_segments), 0), func.coalesce(func.sum(Frame.n_samples), 0))
        .where(Frame.sequence_id == seq.id)
    ).one()
    constraints = session.scalar(select(func.count()).where(PairConstraint.sequence_id == seq.id)) or 0
    return {
        "frames": int(frames),
        "segments": int(segments),
        "samples": int(samples),
        "tracks": int(sum(by_status.values())),
        "tracks_by_status": {k: int(v) for k, v in by_status.items()},
        "constraints": int(constraints),
    }


# built once: review actions check it per call, and building a statement costs more than running it
_SEQUENCE_STATUS = select(Sequence.__table__.c.status).where(Sequence.__table__.c.id == bindparam("sequence_id"))


def check_ready(sequence_id: int, status: str | None, then: str) -> None:
    """The one ready check: Conflict (409) unless the sequence's `status` is "ready" (ingested);
    `then` ends the message with what waits for it ("tracks can be reviewed once it is ready")."""
    if status != "ready":
        raise Conflict(f"sequence {sequence_id} is {status}; {then}")


def require_ready(session: Session, sequence_id: int, then: str) -> None:
    """`check_ready` on the sequence's stored status (None when it does not exist)."""
    check_ready(sequence_id, session.connection().scalar(_SEQUENCE_STATUS, {"sequence_id": sequence_id}), then)
