"""The service's work done in this process, for the one-machine commands (`label`, `demo`,
`train`, `export`): free ports checked before any work, the local admin and operator, sequences
found by path or id, and a job queued and followed to its end with a progress bar.

A job queued here goes through the same job types and the same jobs table as one queued over
REST, so a worker of a running `tracklabel label` may run it too; this process runs queued jobs
itself until its own is done, and follows it either way.
"""

from __future__ import annotations

import io
import logging
import socket
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from pydantic import ValidationError

from app import crud
from app.core.config import Settings
from app.core.db import Database
from app.jobs import policy
from app.models import Job, Sequence
from pipeline.errors import ConfigError, TracklabelError
from pipeline.progress import QUIET, Progress

FINISHED = ("succeeded", "failed", "cancelled")


def check_ports(host: str, ports: dict[str, int]) -> None:
    """ConfigError naming the option of the first port (by option name) that cannot be bound on
    `host`: found before minutes of ingest, not after (port 0 = any free port, always fine)."""
    for option, port in ports.items():
        if port == 0:
            continue
        with socket.socket(socket.AF_INET6 if ":" in host else socket.AF_INET) as s:
            try:
                s.bind((host, port))
            except OSError as exc:
                raise ConfigError(f"port {port} on {host} is in use ({exc.strerror}): choose another with {option} N") from None


def token_for(db: Database, name: str, role: str) -> str:
    """A new token for user `name`, creating the user (with `role`) when needed."""
    with db.write() as s:
        user_id = crud.user_id_by_name(s, name)
        token = crud.create_user(s, name, role)[1] if user_id is None else crud.create_token(s, user_id)
        s.commit()
    return token


def user_id(db: Database, name: str) -> int:
    with db.read() as s:
        uid = crud.user_id_by_name(s, name)
    if uid is None:
        raise ConfigError(f"no user {name!r} in this database")
    return int(uid)


def find_sequence(db: Database, ref: str) -> Sequence:
    """The sequence registered at path `ref` (the newest one), or with id `ref`; a ConfigError
    that lists the registered ones otherwise."""
    path = str(Path(ref).expanduser().resolve())
    with db.read() as s:
        seq = crud.sequence_at_path(s, path)
        if seq is None and ref.isdigit():
            seq = crud.find_sequence_by_id(s, int(ref))
        known = crud.sequence_paths(s)
        if seq is not None:
            s.expunge(seq)
            return seq
    listing = "; ".join(f"{i}: {p}" for i, p in known) or "none (run tracklabel label SEQ first)"
    raise ConfigError(f"{ref}: no sequence registered at this path or with this id; registered: {listing}")


def queue_job(db: Database, job_type: str, params: dict[str, Any], user: int | None) -> int:
    """Validate and queue a job as an admin's REST call would (prepare, admin priority)."""
    from app.crud.ingest_rows import note_queued
    from app.jobs.registry import get_job_type, load_job_types

    load_job_types()
    jt = get_job_type(job_type)
    try:
        checked = jt.params.model_validate(params)
    except ValidationError as exc:
        first = exc.errors()[0]
        raise ConfigError(f"{job_type} {'.'.join(str(p) for p in first['loc'])}: {first['msg']}") from None
    with db.write() as s:
        if jt.prepare is not None:
            jt.prepare(s, checked)
        job = crud.create_job(s, jt.name, checked.model_dump(mode="json"), user, policy.ADMIN_PRIORITY)
        if jt.name == "ingest":
            note_queued(s, checked.sequence_id, job.id)
        s.commit()
        return int(job.id)


def run_job(settings: Settings, db: Database, job_id: int, desc: str, progress: Progress = QUIET) -> dict[str, Any]:
    """Run queued jobs in this process until job `job_id` is finished (another worker may take
    it: then follow it), with its progress on a bar; its result, or a TracklabelError naming the
    job's error."""
    from app.worker import Worker

    done = threading.Event()
    worker = Worker(settings, db=db)

    def work() -> None:
        while not done.is_set():
            if not worker.run_once():
                done.wait(settings.worker_poll_seconds)

    thread = threading.Thread(target=work, name=f"local-job-{job_id}", daemon=True)
    quiet = logging.NullHandler()  # a failed job's traceback: its error is reported below instead
    logging.getLogger("tracklabel.worker").addHandler(quiet)
    thread.start()
    try:
        job = _follow(db, job_id, desc, progress)
    finally:
        done.set()
        thread.join()
        logging.getLogger("tracklabel.worker").removeHandler(quiet)
    if job.status != "succeeded":
        first_line = (job.error or job.message or "").strip().splitlines()[:1]  # not the traceback below it
        raise TracklabelError(f"{job.type} job {job_id} {job.status}: {''.join(first_line)}")
    return dict(job.result or {})


def _follow(db: Database, job_id: int, desc: str, progress: Progress) -> Job:
    """Poll the job row until it is finished, moving a 0-100 % bar with its progress and message."""
    shown = 0
    with progress.bar(100, desc, unit="%", bar_format="{desc}: {percentage:3.0f}%|{bar}| {elapsed}{postfix}") as bar:
        while True:
            with db.read() as s:
                job = crud.get_job(s, job_id)
                s.expunge(job)
            pct = int(100 * (1.0 if job.status == "succeeded" else float(job.progress or 0.0)))
            if pct > shown:
                bar.update(pct - shown)
                shown = pct
            bar.set_postfix(step=(job.message or job.status)[:60])
            if job.status in FINISHED:
                return job
            time.sleep(0.5)


def latest_model(db: Database) -> Path:
    """The checkpoint of the newest model trained in this database (button or `tracklabel train`)."""
    with db.read() as s:
        path = crud.newest_model_path(s)
    if path is None:
        raise ConfigError("no model has been trained in this data folder yet: tracklabel train SEQ first")
    return Path(path)


def export_semantickitti(db: Database, settings: Settings, seq: Sequence, out: Path, options: Any) -> list[Path]:
    """The REST export's SemanticKITTI labels (app.services.exports, `options`: ExportOptions), unpacked
    under `out` as sequences/<name>/labels/NNNNNN.label and summary.json (+ chunk_map.json past
    65,535 tracks); the files written."""
    import tarfile

    from app.artifacts import ArtifactStore
    from app.services.exports import semantickitti_tar
    from app.services.point_labels import point_label_plan

    with db.read() as s:
        plan = point_label_plan(s, crud.get_sequence(s, seq.id), options)
    stream = _ChunkReader(semantickitti_tar(plan, ArtifactStore(settings.artifacts_path)))
    out.mkdir(parents=True, exist_ok=True)
    written = []
    with tarfile.open(fileobj=stream, mode="r|") as tar:
        for member in tar:
            tar.extract(member, out, filter="data")
            written.append(out / member.name)
    return written


class _ChunkReader(io.RawIOBase):
    """A readable file over an iterator of byte chunks (the streamed tar)."""

    def __init__(self, chunks: Iterator[bytes]) -> None:
        self.chunks, self.buf = chunks, b""

    def readable(self) -> bool:
        return True

    def readinto(self, b: Any) -> int:
        while not self.buf:
            chunk = next(self.chunks, None)
            if chunk is None:
                return 0
            self.buf = chunk
        n = min(len(b), len(self.buf))
        b[:n], self.buf = self.buf[:n], self.buf[n:]
        return n
