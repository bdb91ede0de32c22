"""Factory helpers: users with tokens, registered sequences, and sequences ingested through the
real ingest job with the fake pipeline."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from sqlalchemy import select

from app import crud
from app.core.config import Settings
from app.core.db import Database
from app.models import Job, Sequence, Track
from app.worker import Worker
from tests.app.fakes import fake_pipeline


@dataclass(frozen=True)
class Caller:
    id: int
    name: str
    role: str
    token: str

    @property
    def auth(self) -> crud.AuthUser:
        return crud.AuthUser(self.id, self.name, self.role)

    @property
    def headers(self) -> dict[str, str]:
        return {"Authorization": f"Bearer {self.token}"}


class Factory:
    def __init__(self, db: Database, settings: Settings) -> None:
        self.db = db
        self.settings = settings
        self._n = 0

    def user(self, role: str = "operator", name: str | None = None) -> Caller:
        self._n += 1
        name = name or f"{role}{self._n}"
        with self.db.write() as s:
            user, token = crud.create_user(s, name, role)
            return Caller(user.id, user.name, user.role, token)

    def assign(self, caller: Caller, sequence_id: int) -> None:
        """An admin's assignment of `caller` to the sequence (operators queue jobs only there); a
        second call changes nothing."""
        with self.db.write() as s:
            if not crud.list_assignments(s, sequence_id, caller.id):
                crud.create_assignment(s, sequence_id, caller.id, caller.id)

    def sequence_folder(self, name: str = "seq") -> Path:
        folder = self.settings.data_roots[0] / name
        (folder / "velodyne").mkdir(parents=True, exist_ok=True)
        (folder / "velodyne" / "000000.bin").write_bytes(b"\0" * 16)
        return folder

    def registered_sequence(self, name: str = "seq", admin: Caller | None = None, label_set: str = "paper") -> int:
        folder = self.sequence_folder(name)
        admin = admin or self.user("admin")
        with self.db.write() as s:
            _, seq = crud.create_dataset(s, folder, name, "kitti", None, admin.id, label_set)
            s.commit()
            return seq.id

    def queue_ingest(self, sequence_id: int, user_id: int | None = None, force: bool = False) -> int:
        with self.db.write() as s:
            job = crud.create_job(s, "ingest", {"sequence_id": sequence_id, "force": force}, user_id)
            s.commit()
            return job.id

    def ingested_sequence(self, n_frames: int = 6, n_objects: int = 4, name: str = "seq",
                          label_set: str = "paper") -> int:
        """A sequence (of the preset `label_set`) ingested by the real ingest job over the fake
        pipeline; returns its id."""
        seq_id = self.registered_sequence(name, label_set=label_set)
        self.queue_ingest(seq_id)
        with fake_pipeline(n_frames=n_frames, n_objects=n_objects):
            assert Worker(self.settings, db=self.db).run_once()
        with self.db.read() as s:
            seq = s.get(Sequence, seq_id)
            assert seq is not None and seq.status == "ready", (seq and seq.status, self.last_job_error())
        return seq_id

    def last_job_error(self) -> str | None:
        with self.db.read() as s:
            return s.scalars(select(Job.error).order_by(Job.id.desc()).limit(1)).first()

    def track_ids(self, sequence_id: int) -> list[int]:
        with self.db.read() as s:
            return list(s.scalars(select(Track.id).where(Track.sequence_id == sequence_id).order_by(Track.id)).all())

    def track(self, track_id: int) -> Track:
        with self.db.read() as s:
            t = s.get(Track, track_id)
            assert t is not None
            return t


def simulated_campus(tmp_path_factory: Any, frames: int, seed: int) -> Path:
    """A few frames of the simulated campus (SemanticKITTI layout) in a fresh temporary folder."""
    from research.simulation import simulate_sequence

    out = tmp_path_factory.mktemp("sim") / "campus"
    simulate_sequence(out, frames=frames, seed=seed)
    return out


def ingest_through_api(client: Any, factory: Factory, settings: Settings, db: Database, path: Path,
                       label_set: str | dict[str, Any] = "paper") -> tuple[dict[str, Any], dict[str, Any], Caller]:
    """Register `path` (under a second data root) with `label_set` (a preset's name or a label set
    as data) as an admin and run its ingest job with the real pipeline: (the registered sequence,
    the finished ingest job, the admin)."""
    settings.data_roots.append(path.parent)
    admin = factory.user("admin")
    r = client.post("/api/v1/datasets", json={"path": str(path), "label_set": label_set}, headers=admin.headers)
    assert r.status_code == 201, r.text
    seq = r.json()["sequences"][0]
    assert Worker(settings, db=db).run_once()
    job = client.get(f"/api/v1/jobs/{seq['ingest_job_id']}", headers=admin.headers).json()
    assert job["status"] == "succeeded", job["error"]
    return seq, job, admin
