"""What a running job sees: its id and params, the database, artifacts, and checkpoints.

`ctx.progress(fraction, message)` writes progress into the job row and is the checkpoint where a
cancelled job (or one whose lease another worker took over) stops, by raising.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass, field

from app.artifacts import ArtifactStore
from app.core.config import Settings
from app.core.db import Database
from app.crud.jobs import update_running_job


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
        values = {"progress": float(min(max(fraction, 0.0), 1.0)), "message": message[:2000]}
        with self.db.write() as s:
            running = update_running_job(s, self.job_id, self.worker_id, values)
        if not running.owned:
            self.lease_lost.set()
        if running.cancel_requested:
            self.cancelled.set()
        self.checkpoint()
