"""What a running job sees: its id and params, the database, artifacts, and checkpoints.

`ctx.progress(fraction, message)` writes progress into the job row and is the checkpoint where a
cancelled job (or one whose lease another worker took over) stops, by raising.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass, field

from sqlalchemy import select, update

from app.artifacts import ArtifactStore
from app.core.config import Settings
from app.core.db import Database
from app.models import Job


class JobStopped(Exception):
    """Raised at a checkpoint; `reason` is "cancelled", "lease lost" or "timed out"."""

    def __init__(self, reason: str) -> None:
        super().__init__(reason)
        self.reason = reason


@dataclass
class JobContext:
    job_id: int
    attempt: int
    worker_id: str
    db: Database
    settings: Settings
    artifacts: ArtifactStore
    user_id: int | None = None
    cancelled: threading.Event = field(default_factory=threading.Event)
    lease_lost: threading.Event = field(default_factory=threading.Event)
    # set (with `cancelled`, which long handlers poll) when the job ran past its type's limit
    timed_out: threading.Event = field(default_factory=threading.Event)

    def checkpoint(self) -> None:
        """Raise JobStopped when the job was cancelled or its lease is gone."""
        if self.lease_lost.is_set():
            raise JobStopped("lease lost")
        if self.timed_out.is_set():
            raise JobStopped("timed out")
        if self.cancelled.is_set():
            raise JobStopped("cancelled")

    def progress(self, fraction: float, message: str = "") -> None:
        """Record progress in [0, 1] and a message in the job row, then check for cancellation."""
        with self.db.write() as s:
            res = s.execute(
                update(Job)
                .where(Job.id == self.job_id, Job.worker_id == self.worker_id, Job.status == "running")
                .values(progress=float(min(max(fraction, 0.0), 1.0)), message=message[:2000])
            )
            cancel = s.scalar(select(Job.cancel_requested).where(Job.id == self.job_id))
            s.commit()
        if res.rowcount != 1:
            self.lease_lost.set()
        if cancel:
            self.cancelled.set()
        self.checkpoint()
