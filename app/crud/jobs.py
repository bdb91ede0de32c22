"""Queueing and cancelling jobs."""

from __future__ import annotations

from typing import Any

from sqlalchemy import select
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
