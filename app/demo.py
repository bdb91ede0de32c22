"""`tracklabel demo`: simulate the campus scene, register and ingest it, and hand out tokens.

1. simulate OUT/sequence (skipped when it is already there);
2. upgrade the database under OUT;
3. create the users `admin` and `operator` (or new tokens for them);
4. register the sequence and run its ingest job in this process;
5. return the URL and the operator's token; the CLI then serves.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from sqlalchemy import select

from app import crud
from app.core.config import Settings
from app.core.db import Database
from app.core.migrate import upgrade
from app.models import Job, Sequence, User
from pipeline.progress import TqdmProgress


@dataclass(frozen=True)
class DemoInfo:
    settings: Settings
    sequence_id: int
    url: str
    admin_token: str
    operator_token: str
    ingest_result: dict


def demo_settings(out: Path, port: int) -> Settings:
    out = out.resolve()
    return Settings(data_dir=out, data_roots=[out], port=port)


def token_for(db: Database, name: str, role: str) -> str:
    """A new token for user `name`, creating the user when needed."""
    with db.write() as s:
        user_id = s.scalar(select(User.id).where(User.name == name))
        if user_id is None:
            return crud.create_user(s, name, role)[1]
        return crud.create_token(s, user_id)


def prepare_demo(
    out: Path, frames: int, seed: int, port: int, log: Callable[[str], None] = print
) -> DemoInfo:
    from app.jobs import load_job_types
    from app.worker import Worker
    from research.simulation import simulate_sequence

    settings = demo_settings(out, port)
    seq_dir = settings.data_dir / "sequence"
    if not (seq_dir / "velodyne").is_dir():
        log(f"1. simulating {frames} frames (seed {seed}) into {seq_dir}")
        log(simulate_sequence(seq_dir, frames=frames, seed=seed, progress=TqdmProgress()).describe())
    else:
        log(f"1. using the simulated sequence in {seq_dir}")
    log("2. upgrading the database")
    upgrade(settings.db_url)
    db = Database.from_settings(settings)
    load_job_types(settings.job_modules)
    admin_token = token_for(db, "admin", "admin")
    operator_token = token_for(db, "operator", "operator")

    with db.write() as s:
        seq = s.scalars(select(Sequence).where(Sequence.path == str(seq_dir.resolve()))).first()
        if seq is None:
            admin_id = s.scalar(select(User.id).where(User.name == "admin"))
            assert admin_id is not None
            _, seq = crud.create_dataset(s, seq_dir.resolve(), "campus", "kitti", None, admin_id)
        seq_id, status = seq.id, seq.status
        s.commit()
    result: dict = {}
    if status != "ready":
        log("3. ingesting (segmentation, samples, association)")
        with db.write() as s:
            job = crud.create_job(s, "ingest", {"sequence_id": seq_id, "force": False}, None)
            s.commit()
            job_id = job.id
        worker = Worker(settings, db=db)
        while worker.run_once():
            pass
        with db.read() as s:
            job_row = s.get(Job, job_id)
            assert job_row is not None
            if job_row.status != "succeeded":
                from pipeline.errors import TracklabelError

                raise TracklabelError(f"demo ingest {job_row.status}: {job_row.error}")
            result = dict(job_row.result or {})
        log(
            f"   {result.get('frames')} frames, {result.get('tracks')} tracks, "
            f"{result.get('constraints')} constraints"
        )
    else:
        log("3. sequence already ingested")
    db.dispose()
    return DemoInfo(settings, seq_id, f"http://{settings.host}:{port}/api/v1/docs", admin_token, operator_token, result)
