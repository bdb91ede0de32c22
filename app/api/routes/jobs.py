from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Query, status
from pydantic import ValidationError
from sqlalchemy import select

from app import crud
from app.api.deps import CurrentUser, IdPath, SessionDep, WriteSessionDep
from app.core.errors import Forbidden, Invalid, NotFound
from app.crud import AuthUser
from app.jobs.registry import get_job_type, job_types
from app.models import Job
from app.schemas import JobCreate, JobPublic, JobStatus, JobTypePublic

router = APIRouter(tags=["jobs"])


@router.get("/job-types")
def list_job_types(_user: CurrentUser) -> list[JobTypePublic]:
    """The job types this service knows, who may start them and their params schema."""
    return [
        JobTypePublic(
            name=jt.name, admin_only=jt.admin_only, description=jt.description, params_schema=jt.params.model_json_schema()
        )
        for jt in job_types()
    ]


@router.post("/jobs", status_code=status.HTTP_202_ACCEPTED)
def create_job(body: JobCreate, user: CurrentUser, session: WriteSessionDep) -> JobPublic:
    """Queue a job `{type, params}`; a worker runs it. Unknown type or bad params -> 422;
    admin-only types (e.g. `ingest`) from an operator -> 403."""
    try:
        jt = get_job_type(body.type)
    except KeyError as exc:
        raise Invalid(str(exc.args[0])) from None
    if jt.admin_only and not user.is_admin:
        raise Forbidden(f"job type {jt.name!r} needs the admin role")
    try:
        params = jt.params.model_validate(body.params)
    except ValidationError as exc:
        first = exc.errors()[0]
        raise Invalid(f"params.{'.'.join(str(p) for p in first['loc'])}: {first['msg']}") from None
    if jt.prepare is not None:
        jt.prepare(session, params)
    job = crud.create_job(session, jt.name, params.model_dump(mode="json"), user.id)
    if jt.name == "ingest":
        from app.models import Sequence

        seq = session.get(Sequence, params.sequence_id)
        if seq is not None:
            seq.ingest_job_id = job.id
    session.commit()
    return JobPublic.model_validate(job)


@router.get("/jobs")
def list_jobs(
    user: CurrentUser,
    session: SessionDep,
    status: JobStatus | None = None,
    limit: Annotated[int, Query(ge=1, le=1000)] = 100,
    offset: Annotated[int, Query(ge=0, le=2**31 - 1)] = 0,
) -> list[JobPublic]:
    """Jobs, newest first: all of them for an admin, the caller's own for an operator."""
    q = select(Job).order_by(Job.id.desc()).limit(limit).offset(offset)
    if status is not None:
        q = q.where(Job.status == status)
    if not user.is_admin:
        q = q.where(Job.created_by_id == user.id)
    return [JobPublic.model_validate(j) for j in session.scalars(q).all()]


def _visible_job(session: SessionDep, job_id: int, user: AuthUser) -> Job:
    job = session.get(Job, job_id)
    if job is None:
        raise NotFound(f"job {job_id} not found")
    if not user.is_admin and job.created_by_id != user.id:
        raise Forbidden("operators see only their own jobs")
    return job


@router.get("/jobs/{job_id}")
def read_job(job_id: IdPath, user: CurrentUser, session: SessionDep) -> JobPublic:
    """A job's status, progress, message and result."""
    return JobPublic.model_validate(_visible_job(session, job_id, user))


@router.post("/jobs/{job_id}/cancel", status_code=status.HTTP_202_ACCEPTED)
def cancel_job(job_id: IdPath, user: CurrentUser, session: WriteSessionDep) -> JobPublic:
    """Cancel a queued job, or ask a running one to stop at its next checkpoint."""
    _visible_job(session, job_id, user)
    return JobPublic.model_validate(crud.cancel_job(session, job_id, by=user.name))
