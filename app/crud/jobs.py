"""Queueing, claiming, updating and cancelling jobs (the worker's queries live here too)."""

from __future__ import annotations

from dataclasses import dataclass
from datetime import datetime, timedelta
from typing import Any

from sqlalchemy import case, func, or_, select, update
from sqlalchemy.orm import Session

from app.core.errors import Conflict, NotFound
from app.crud.rows import get_or_404
from app.models import Job, utcnow


def create_job(
    session: Session, job_type: str, params: dict[str, Any], user_id: int | None, priority: int = 0
) -> Job:
    """Queue a job (params already validated by its job type, the caller authorised by
    app.jobs.policy). Flushes, does not commit."""
    job = Job(type=job_type, params=params, status="queued", created_by_id=user_id, message="queued", priority=priority)
    session.add(job)
    session.flush()
    return job


def cancel_job(session: Session, job_id: int, by: str = "") -> Job:
    """Cancel a queued job at once; ask a running one to stop at its next checkpoint. Commits.
    `by` (the caller's name) goes into the job's message."""
    job = session.scalars(select(Job).where(Job.id == job_id).with_for_update()).first()
    if job is None:
        raise NotFound(f"job {job_id} not found")
    if job.status == "queued":
        job.status = "cancelled"
        job.finished_at = utcnow()
        job.message = "cancelled before it started" + (f" by {by}" if by else "")
    elif job.status == "running":
        job.cancel_requested = True
        job.message = "cancel requested" + (f" by {by}" if by else "")
    else:
        raise Conflict(f"job {job_id} is already {job.status}")
    session.commit()
    return job


def list_jobs(session: Session, status: str | None, job_type: str | None, created_by: int | None, limit: int,
              offset: int) -> list[Job]:
    """Jobs, newest first; `created_by`: only that user's (None: everyone's)."""
    q = select(Job).order_by(Job.id.desc()).limit(limit).offset(offset)
    if status is not None:
        q = q.where(Job.status == status)
    if job_type is not None:
        q = q.where(Job.type == job_type)
    if created_by is not None:
        q = q.where(Job.created_by_id == created_by)
    return list(session.scalars(q).all())


def get_job(session: Session, job_id: int) -> Job:
    return get_or_404(session, Job, job_id, "job")


def job_owner(session: Session, job_id: int) -> int | None:
    """The id of the user who queued the job (None: the service itself, or no such job)."""
    return session.scalar(select(Job.created_by_id).where(Job.id == job_id))


def queued_count(session: Session, user_id: int) -> int:
    """How many of the user's jobs wait in the queue."""
    return int(session.scalar(
        select(func.count()).select_from(Job).where(Job.created_by_id == user_id, Job.status == "queued")
    ) or 0)


def job_runs(session: Session, job_type: str) -> list[tuple[str, dict[str, Any]]]:
    """(status, params) of every job of one type."""
    return [(status, params) for status, params in session.execute(
        select(Job.status, Job.params).where(Job.type == job_type)
    ).all()]


def _users_at_running_limit(limit: int) -> Any:
    """SQL: ids of users who already have `limit` running jobs (their queued jobs wait)."""
    return (
        select(Job.created_by_id)
        .where(Job.status == "running", Job.created_by_id.is_not(None))
        .group_by(Job.created_by_id)
        .having(func.count() >= limit)
    )


def _claimable_owner(limit: int) -> Any:
    """SQL condition on a queued job: its owner is below the running limit."""
    return or_(Job.created_by_id.is_(None), Job.created_by_id.not_in(_users_at_running_limit(limit)))


@dataclass(frozen=True)
class ClaimedJob:
    id: int
    type: str
    params: dict[str, Any]
    attempt: int
    created_by_id: int | None


@dataclass(frozen=True)
class ClaimRules:
    """What a worker may claim: its job types, the per-user running limit, the attempts a job
    gets before an expired lease fails it, and how long a new lease lasts."""

    types: list[str]
    max_running_per_user: int
    max_attempts: int
    lease: timedelta


def _next_claimable(session: Session, rules: ClaimRules, now: datetime) -> Job | None:
    """The runnable job first in line (locked; `SKIP LOCKED` on PostgreSQL)."""
    return session.scalars(
        select(Job)
        .where(
            Job.type.in_(rules.types),
            or_(
                (Job.status == "queued") & _claimable_owner(rules.max_running_per_user),
                (Job.status == "running") & (Job.lease_expires_at < now),
            ),
        )
        .order_by(Job.priority.desc(), Job.id)
        .limit(1)
        .with_for_update(skip_locked=True)
    ).first()


def claim_job(session: Session, rules: ClaimRules, worker_id: str) -> ClaimedJob | None:
    """Claim one job for `worker_id`, or None when nothing is runnable. A running job whose lease
    expired is cancelled (a cancel was requested) or failed (out of attempts) instead, and the
    next one is looked at. Commits each change."""
    while True:
        now = utcnow()
        job = _next_claimable(session, rules, now)
        if job is None:
            return None
        if job.status == "running" and (job.cancel_requested or job.attempts >= rules.max_attempts):
            job.status = "cancelled" if job.cancel_requested else "failed"
            job.error = None if job.cancel_requested else f"lease expired after {job.attempts} attempts"
            job.finished_at = now
            job.lease_expires_at = None
            session.commit()
            continue
        job.status = "running"
        job.worker_id = worker_id
        job.attempts += 1
        job.lease_expires_at = now + rules.lease
        job.heartbeat_at = now
        # never before its creation, whichever machine's clock stamped that
        job.started_at = job.started_at or max(now, job.created_at)
        # the worker's host and pid stay in worker_id, for admins and the logs
        job.message = f"claimed by a worker (attempt {job.attempts})"
        claimed = ClaimedJob(job.id, job.type, dict(job.params or {}), job.attempts, job.created_by_id)
        session.commit()
        return claimed


@dataclass(frozen=True)
class RunningJob:
    """After an update of a running job: whether the worker still owns it (else another worker
    took over its lease, or it finished) and whether a cancel was requested."""

    owned: bool
    cancel_requested: bool


def update_running_job(session: Session, job_id: int, worker_id: str, values: dict[str, Any]) -> RunningJob:
    """Set `values` on the job while `worker_id` runs it; commits."""
    res = session.execute(
        update(Job).where(Job.id == job_id, Job.worker_id == worker_id, Job.status == "running").values(**values)
    )
    cancel = session.scalar(select(Job.cancel_requested).where(Job.id == job_id))
    session.commit()
    return RunningJob(res.rowcount == 1, bool(cancel))


def finish_job_values(status: str, result: dict[str, Any] | None, error: str | None, message: str) -> dict[str, Any]:
    """The columns a finished job gets (`update_running_job` writes them)."""
    now = utcnow()
    values: dict[str, Any] = {
        "status": status,
        "finished_at": case((Job.started_at > now, Job.started_at), else_=now),  # never before the start
        "lease_expires_at": None,
        "message": message or status,
    }
    if status == "succeeded":
        values.update(result=result or {}, progress=1.0)
    if error is not None:
        values["error"] = error
    return values
