from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Query, status
from pydantic import ValidationError

from app import crud
from app.api.deps import CurrentUser, IdPath, SessionDep, SettingsDep, WriteSessionDep
from app.api.errors import ErrorBody
from app.api.redact import job_public
from app.core.errors import Forbidden, Invalid
from app.crud import AuthUser
from app.jobs import policy
from app.jobs.registry import get_job_type, job_types
from app.models import Job
from app.schemas import JobCreate, JobPublic, JobStatus, JobTypePublic

router = APIRouter(tags=["jobs"])


@router.get("/job-types")
def list_job_types(_user: CurrentUser, settings: SettingsDep) -> list[JobTypePublic]:
    """The job types this service knows, who may start them (and within which bounds), their
    maximum run time and their params schema."""
    return [
        JobTypePublic(
            name=jt.name, admin_only=jt.rule_for_operators() is None, description=jt.description,
            params_schema=jt.params.model_json_schema(), **policy.describe(jt, settings),
        )
        for jt in job_types()
    ]


@router.post("/jobs", status_code=status.HTTP_202_ACCEPTED, responses={429: {"description": "Too many queued jobs."}})
def create_job(body: JobCreate, user: CurrentUser, session: WriteSessionDep, settings: SettingsDep) -> JobPublic:
    """Queue a job `{type, params}`; a worker runs it, admins' jobs first. Unknown type or bad
    params -> 422; a type or params beyond the caller's role (app/jobs/policy.py) -> 403; past the
    per-user queue limit -> 429."""
    try:
        jt = get_job_type(body.type)
    except KeyError as exc:
        raise Invalid(str(exc.args[0])) from None
    if jt.rule_for_operators() is None and not user.is_admin:
        raise Forbidden(f"job type {jt.name!r} needs the admin role")
    try:
        params = jt.params.model_validate(body.params)
    except ValidationError as exc:
        first = exc.errors()[0]
        raise Invalid(f"params.{'.'.join(str(p) for p in first['loc'])}: {first['msg']}") from None
    if jt.prepare is not None:  # 404/409 for what the job needs come first; nothing is committed yet
        jt.prepare(session, params)
    priority = policy.authorize(session, user, jt, params, settings)
    job = crud.create_job(session, jt.name, params.model_dump(mode="json"), user.id, priority)
    if jt.name == "ingest":
        from app.crud.ingest_rows import note_queued

        note_queued(session, params.sequence_id, job.id)
    session.commit()
    return job_public(job, user)


@router.get("/jobs")
def list_jobs(
    user: CurrentUser,
    session: SessionDep,
    status: JobStatus | None = None,
    type: Annotated[str | None, Query(min_length=1, max_length=32, description="Only jobs of this type.")] = None,
    limit: Annotated[int, Query(ge=1, le=1000)] = 100,
    offset: Annotated[int, Query(ge=0, le=2**31 - 1)] = 0,
) -> list[JobPublic]:
    """Jobs, newest first: all of them for an admin, the caller's own for an operator."""
    jobs = crud.list_jobs(session, status, type, None if user.is_admin else user.id, limit, offset)
    return [job_public(j, user) for j in jobs]


def _visible_job(session: SessionDep, job_id: int, user: AuthUser) -> Job:
    job = crud.get_job(session, job_id)
    if not user.is_admin and job.created_by_id != user.id:
        raise Forbidden("operators see only their own jobs")
    return job


OTHERS_JOB = {403: {"description": "An operator asks for another user's job.", "model": ErrorBody}}


@router.get("/jobs/{job_id}", responses=OTHERS_JOB)
def read_job(job_id: IdPath, user: CurrentUser, session: SessionDep) -> JobPublic:
    """A job's status, progress, message and result."""
    return job_public(_visible_job(session, job_id, user), user)


@router.post("/jobs/{job_id}/cancel", status_code=status.HTTP_202_ACCEPTED, responses=OTHERS_JOB)
def cancel_job(job_id: IdPath, user: CurrentUser, session: WriteSessionDep) -> JobPublic:
    """Cancel a queued job, or ask a running one to stop at its next checkpoint."""
    _visible_job(session, job_id, user)
    return job_public(crud.cancel_job(session, job_id, by=user.name), user)
