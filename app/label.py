"""`tracklabel label SEQ` (and the demo's set-up): a sequence made ready to review in this process.

1. upgrade the database in the data folder;
2. create the users `admin` and `operator`, or new tokens for them;
3. register SEQ (any supported format) unless it is registered already;
4. ingest it (segmentation, samples, association) with a progress bar, unless it is ready;
5. return the tokens and the sequence id; the CLI then serves the API and the annotator.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from app import local
from app.core.config import Settings
from app.core.db import Database
from app.core.migrate import upgrade
from pipeline.errors import ConfigError
from pipeline.label_sets import LabelSet
from pipeline.progress import QUIET, Progress


@dataclass(frozen=True)
class Prepared:
    settings: Settings
    sequence_id: int
    admin_token: str
    operator_token: str
    ingest_result: dict[str, Any]


@dataclass(frozen=True)
class Source:
    """What to register: the folder or file, its reader and ingest options."""

    path: Path
    name: str | None = None
    fmt: str = "auto"
    sensor: str = "auto"
    poses: str = "file"
    reingest: bool = False  # process a ready sequence again (its reviews are dropped)
    label_set: str | None = None  # a preset or label set file; None: paper, or what it was registered with


def label_settings(data_dir: Path | None, seq: Path, **overrides: Any) -> Settings:
    """The environment's settings with `data_dir` (when given) and SEQ added to the data roots:
    the owner registers their own recording wherever it lies, with the folders its links lead to."""
    base = Settings(**({"data_dir": data_dir} if data_dir is not None else {}), **overrides)
    return base.model_copy(update={"data_roots": [*base.data_roots, *own_roots(seq)]})


def own_roots(seq: Path) -> list[Path]:
    """SEQ (resolved) and the folders that the links inside it point into."""
    seq = seq.expanduser().resolve()
    roots = {seq}
    if seq.is_dir():
        for folder, dirs, files in os.walk(seq):
            for name in (*dirs, *files):
                entry = Path(folder) / name
                if entry.is_symlink():
                    target = entry.resolve()
                    roots.add(target if target.is_dir() else target.parent)
    return sorted(roots)


def prepare(settings: Settings, src: Source, log: Callable[[str], None] = print, progress: Progress = QUIET) -> Prepared:
    """Steps 1-4 of the module docstring; ConfigError / DataError / TracklabelError on bad input."""
    from app.jobs import load_job_types

    log(f"database: {settings.db_url}")
    upgrade(settings.db_url)
    db = Database.from_settings(settings)
    try:
        load_job_types(settings.job_modules)
        admin, operator = local.token_for(db, "admin", "admin"), local.token_for(db, "operator", "operator")
        seq_id = _register(db, src, local.user_id(db, "admin"), log)
        result = _ingest(settings, db, seq_id, src, log, progress)
    finally:
        db.dispose()
    return Prepared(settings, seq_id, admin, operator, result)


def _register(db: Database, src: Source, admin_id: int, log: Callable[[str], None]) -> int:
    from app import crud
    from pipeline.io.registry import detect_format, reader_names

    path = src.path.expanduser().resolve()
    if not path.exists():
        raise ConfigError(f"{src.path}: no such file or folder")
    label_set, definition = _label_set(src.label_set)
    with db.read() as s:
        existing = crud.registered_sequence_id(s, path)
        has = None if existing is None else crud.sequence_label_set(s, existing)
    if existing is not None:
        if src.label_set is not None and has is not None and not (has.name == label_set.name
                                                                   and has.same_classes(label_set)):
            raise ConfigError(f"--label-set {src.label_set}: sequence {existing} was registered with label set "
                              f"{has.name!r}; its labels speak those classes")
        log(f"sequence {existing}: {path} (registered before)")
        return existing
    if src.fmt != "auto" and src.fmt not in reader_names():
        raise ConfigError(f"unknown format {src.fmt!r}; known: {', '.join(reader_names())}")
    fmt = detect_format(path) if src.fmt == "auto" else src.fmt
    config = None if src.sensor == "auto" else {"sensor": {"name": src.sensor}}
    with db.write() as s:
        _, seq = crud.create_dataset(s, path, src.name, fmt, config, admin_id, label_set.name, definition)
        s.commit()
        seq_id = int(seq.id)
    log(f"sequence {seq_id}: {path} ({fmt}, label set {label_set.name}) registered")
    return seq_id


def _label_set(name_or_path: str | None) -> tuple[LabelSet, dict[str, Any] | None]:
    """The label set to register with and the definition to store (None for a preset, stored by
    name); ConfigError naming the file and field of one that is not valid, or of a file that takes
    a preset's name with other classes."""
    from pipeline.label_sets import DEFAULT_LABEL_SET, load_label_set, preset, preset_names

    label_set = load_label_set(name_or_path or DEFAULT_LABEL_SET)
    if label_set.name not in preset_names():
        return label_set, label_set.model_dump(mode="json")
    if label_set.same_classes(preset(label_set.name)):
        return label_set, None
    raise ConfigError(f"{name_or_path}: field name: {label_set.name!r} is a preset's name; name your label set "
                      "otherwise")


def _ingest(settings: Settings, db: Database, seq_id: int, src: Source, log: Callable[[str], None],
            progress: Progress) -> dict[str, Any]:
    """Queue the ingest (or pick up one queued before) and run it here; {} when it is ready."""
    from app.crud.datasets import get_sequence
    from app.crud.ingest_rows import active_ingest_job

    with db.read() as s:
        status = get_sequence(s, seq_id).status
        job_id = active_ingest_job(s, seq_id)
    if status == "ready" and not src.reingest:
        log("already ingested: its tracks and reviews are kept (--reingest processes it again)")
        return {}
    if job_id is None:
        job_id = local.queue_job(db, "ingest", {"sequence_id": seq_id, "force": src.reingest, "poses": src.poses}, None)
    log(f"ingesting (segmentation, samples, association; poses: {src.poses})")
    result = local.run_job(settings, db, job_id, "ingest", progress)
    log(f"{result.get('frames')} frames, {result.get('tracks')} tracks, {result.get('constraints')} constraints")
    return result
