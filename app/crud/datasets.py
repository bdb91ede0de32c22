"""Datasets and sequences: registration under the data roots, statistics, the ready check."""

from __future__ import annotations

from pathlib import Path, PurePath
from typing import Any

from sqlalchemy import bindparam, func, select
from sqlalchemy.orm import Session

from app.core.errors import Conflict, Forbidden, Invalid, NotFound
from app.crud.rows import get_or_404
from app.data_roots import DataRoots, sensor_file
from app.models import Dataset, Frame, PairConstraint, Sequence, Track
from pipeline.label_sets import DEFAULT_LABEL_SET


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
            try:
                if real.exists():
                    return real
            except OSError:  # a part longer than the file system takes: nothing is there
                continue
    if not inside:
        raise Forbidden("path is outside the configured data roots")
    raise NotFound(f"no such file or folder under the data roots: {raw}")


def check_tree_inside_roots(path: Path, roots: list[Path]) -> DataRoots:
    """Forbidden (403) naming the first file or folder under `path` (or `path` itself) whose real
    path lies outside every root, whatever the number of link hops, or that is a hard link to a
    file with a name outside them (app/data_roots.py). Checked at registration and again when
    ingest opens the sequence; returns the roots with the hard links it cleared."""
    data_roots = DataRoots.of(roots)
    data_roots.check_tree(path)
    return data_roots


def pipeline_config(settings_path: Path | None, overrides: dict[str, Any] | None) -> Any:
    """The settings' pipeline config file with a sequence's overrides (ingest and the repairs)."""
    from pipeline.config import load_config

    cfg = load_config(settings_path)
    return cfg.override(overrides) if overrides else cfg


def check_sensor_file(config: Any, roots: list[Path]) -> None:
    """A pipeline config's sensor file (an Ouster json) must lie under the roots too (403)."""
    name = getattr(getattr(config, "sensor", None), "name", "auto")
    path = sensor_file(str(name))
    if path is not None:
        DataRoots.of(roots).check_file(path, f"sensor file {path.name}")


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
    label_set: str = DEFAULT_LABEL_SET,
    label_set_definition: dict[str, Any] | None = None,
) -> tuple[Dataset, Sequence]:
    """Register one sequence path (already resolved and checked) with its label set: a preset's
    name, or the name of the set `label_set_definition` gives as data. Flushes, does not commit."""
    ds = Dataset(name=name or path.name, path=str(path), created_by_id=user_id)
    session.add(ds)
    session.flush()
    seq = Sequence(dataset_id=ds.id, name=name or path.name, path=str(path), format=fmt, config=config,
                   label_set=label_set, label_set_definition=label_set_definition)
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


def list_datasets(session: Session) -> list[Dataset]:
    return list(session.scalars(select(Dataset).order_by(Dataset.id)).all())


def get_dataset(session: Session, dataset_id: int) -> Dataset:
    return get_or_404(session, Dataset, dataset_id, "dataset")


def dataset_sequences(session: Session, dataset_id: int) -> list[Sequence]:
    return list(session.scalars(select(Sequence).where(Sequence.dataset_id == dataset_id).order_by(Sequence.id)).all())


def list_sequences(session: Session, status: str | None = None) -> list[Sequence]:
    q = select(Sequence).order_by(Sequence.id)
    if status is not None:
        q = q.where(Sequence.status == status)
    return list(session.scalars(q).all())


def get_sequence(session: Session, sequence_id: int) -> Sequence:
    return get_or_404(session, Sequence, sequence_id, "sequence")


def sequence_at_path(session: Session, path: str) -> Sequence | None:
    """The newest sequence registered at `path` (resolved), None when there is none."""
    return session.scalars(select(Sequence).where(Sequence.path == path).order_by(Sequence.id.desc())).first()


def find_sequence_by_id(session: Session, sequence_id: int) -> Sequence | None:
    return session.get(Sequence, sequence_id)


def sequence_paths(session: Session) -> list[tuple[int, str]]:
    """(id, path) of every registered sequence, by id."""
    return [(int(i), p) for i, p in session.execute(select(Sequence.id, Sequence.path).order_by(Sequence.id)).all()]


def ready_sequence_ids(session: Session) -> list[int]:
    """The ids of the ready sequences, in order."""
    return [int(i) for i in session.scalars(select(Sequence.id).where(Sequence.status == "ready").order_by(Sequence.id))]
