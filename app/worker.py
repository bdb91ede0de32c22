"""The job worker: `tracklabel worker` or `python -m app.worker`.

It claims the oldest runnable job of a type it knows: a queued one, or a running one whose lease
has expired (its worker died). The claim is one transaction: BEGIN IMMEDIATE on SQLite (writers
serialise), `SELECT ... FOR UPDATE SKIP LOCKED` on PostgreSQL (workers skip each other's rows).
While the job runs, a heartbeat thread renews the lease; progress goes into the job row; a cancel
request or a lost lease stops the handler at its next checkpoint. A job whose lease expired
`job_max_attempts` times is marked failed.
"""

from __future__ import annotations

import logging
import os
import signal
import socket
import threading
import time
import traceback
import uuid
from datetime import timedelta
from typing import Any

from pydantic import ValidationError

from app.artifacts import ArtifactStore
from app.core.config import Settings
from app.core.db import Database
from app.crud import jobs as crud_jobs
from app.crud.jobs import ClaimedJob, ClaimRules
from app.jobs import policy
from app.jobs.context import JobContext, JobStopped
from app.jobs.registry import get_job_type, load_job_types
from app.models import utcnow

log = logging.getLogger("tracklabel.worker")


class Worker:
    """Claims and runs jobs. `run_once()` runs at most one job; `run_forever()` polls."""

    def __init__(self, settings: Settings, db: Database | None = None, worker_id: str | None = None) -> None:
        self.settings = settings
        self.db = db or Database.from_settings(settings)
        self.artifacts = ArtifactStore(settings.artifacts_path)
        self.worker_id = worker_id or f"{socket.gethostname()}:{os.getpid()}:{uuid.uuid4().hex[:8]}"
        self.types = load_job_types(settings.job_modules)
        self.stop_event = threading.Event()

    # ------------------------------------------------------------------ claiming
    def claim(self) -> ClaimedJob | None:
        """Claim one job, or None when nothing is runnable."""
        rules = ClaimRules(self.types, self.settings.job_max_running_per_user, self.settings.job_max_attempts,
                           timedelta(seconds=self.settings.job_lease_seconds))
        with self.db.write() as s:
            return crud_jobs.claim_job(s, rules, self.worker_id)

    # ------------------------------------------------------------------ running
    def run_once(self) -> bool:
        """Claim and run one job; False when there was none."""
        claimed = self.claim()
        if claimed is None:
            return False
        self.run(claimed)
        return True

    def run(self, claimed: ClaimedJob) -> None:
        ctx = JobContext(
            job_id=claimed.id,
            attempt=claimed.attempt,
            worker_id=self.worker_id,
            db=self.db,
            settings=self.settings,
            artifacts=self.artifacts,
            user_id=claimed.created_by_id,
        )
        job_type = get_job_type(claimed.type)
        limit = policy.max_run_seconds(job_type, self.settings)
        stop_beat = threading.Event()
        deadline = time.monotonic() + limit
        beat = threading.Thread(
            target=self._heartbeat, args=(ctx, stop_beat, deadline), daemon=True, name="heartbeat"
        )
        beat.start()
        params: Any = None
        try:
            params = _within_cores(job_type.params.model_validate(claimed.params))
            result = job_type.handler(ctx, params)
        except JobStopped as exc:
            if exc.reason == "timed out":
                log.warning("job %s: stopped after its maximum run time of %g s", claimed.id, limit)
                self._stop_hook(job_type, ctx, params, "failed")
                self._finish(ctx, "failed", error=f"exceeded its maximum run time of {limit:g} s",
                             message="stopped: maximum run time exceeded")
            elif exc.reason == "cancelled":
                self._stop_hook(job_type, ctx, params, "cancelled")
                self._finish(ctx, "cancelled", message="cancelled at a checkpoint")
            else:
                log.warning("job %s: lease lost; another worker owns it now", claimed.id)
        except (ValidationError, Exception) as exc:  # noqa: BLE001 - a job's failure must not kill the worker
            log.error("job %s failed: %s", claimed.id, exc)
            if params is not None:
                self._stop_hook(job_type, ctx, params, "failed")
            self._finish(ctx, "failed", error=f"{type(exc).__name__}: {exc}", trace=traceback.format_exc())
        else:
            self._finish(ctx, "succeeded", result=result, message="done")
        finally:
            stop_beat.set()
            beat.join(timeout=5)

    def _stop_hook(self, job_type: Any, ctx: JobContext, params: Any, reason: str) -> None:
        if job_type.on_stop is None:
            return
        try:
            job_type.on_stop(ctx, params, reason)
        except Exception:  # noqa: BLE001
            log.exception("job %s: on_stop hook failed", ctx.job_id)

    def _finish(
        self,
        ctx: JobContext,
        status: str,
        result: dict[str, Any] | None = None,
        error: str | None = None,
        message: str = "",
        trace: str | None = None,
    ) -> None:
        values = crud_jobs.finish_job_values(
            status, result, error if error is None or trace is None else f"{error}\n{trace[-4000:]}", message
        )
        with self.db.write() as s:
            crud_jobs.update_running_job(s, ctx.job_id, self.worker_id, values)

    def _heartbeat(self, ctx: JobContext, stop: threading.Event, deadline: float) -> None:
        lease = timedelta(seconds=self.settings.job_lease_seconds)
        while not stop.wait(self.settings.job_heartbeat_seconds):
            if time.monotonic() > deadline:
                ctx.timed_out.set()
                ctx.cancelled.set()  # long handlers poll `cancelled` between their own checkpoints
            try:
                self.touch_alive()
                with self.db.write() as s:
                    now = utcnow()
                    running = crud_jobs.update_running_job(
                        s, ctx.job_id, self.worker_id, {"lease_expires_at": now + lease, "heartbeat_at": now}
                    )
                if not running.owned:
                    ctx.lease_lost.set()
                    return
                if running.cancel_requested:
                    ctx.cancelled.set()
            except Exception:  # noqa: BLE001 - a missed beat is retried; the lease covers several
                log.exception("job %s: heartbeat failed", ctx.job_id)

    def touch_alive(self) -> None:
        """Mark this worker alive (`worker_alive_file`, for container healthchecks)."""
        path = self.settings.worker_alive_file
        if path is not None:
            path.touch()

    def schedule(self) -> list[int]:
        """Queue the jobs the service starts by itself: the model-in-the-loop runs of sequences
        that reviews have moved on (app/jobs/assist.py). Returns the new jobs' ids."""
        if "assist" not in self.types:
            return []
        from app.jobs import assist

        return assist.schedule(self.db, self.settings)

    def run_forever(self) -> None:
        """Poll for jobs until `stop_event` is set."""
        log.info("worker %s: job types %s", self.worker_id, ", ".join(self.types))
        while not self.stop_event.is_set():
            self.touch_alive()
            try:
                self.schedule()
                ran = self.run_once()
            except Exception:  # noqa: BLE001 - e.g. the database restarting; poll again
                log.exception("worker %s: claim failed", self.worker_id)
                ran = False
            if not ran:
                self.stop_event.wait(self.settings.worker_poll_seconds)

    def start_thread(self) -> threading.Thread:
        """Run `run_forever` in a daemon thread (the in-process worker of `TRACKLABEL_EMBEDDED_WORKER`)."""
        t = threading.Thread(target=self.run_forever, daemon=True, name="worker")
        t.start()
        return t


def _within_cores(params: Any) -> Any:
    """The params with `threads` at most this machine's cores (the API checked its own)."""
    threads = getattr(params, "threads", None)
    cores = policy.machine_cores()
    return params.model_copy(update={"threads": cores}) if threads is not None and threads > cores else params


def main(once: bool = False) -> None:
    """Run a worker with settings from the environment until SIGTERM/SIGINT."""
    from app.core.config import get_settings

    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    worker = Worker(get_settings())
    if once:
        worker.run_once()
        return

    def _stop(signum: int, _frame: object) -> None:
        worker.stop_event.set()

    signal.signal(signal.SIGTERM, _stop)
    signal.signal(signal.SIGINT, _stop)
    worker.run_forever()


if __name__ == "__main__":
    main()
