"""Job policy: who may queue what, with which parameters, how many at a time, and in which order.

- Admins queue every job type with any valid params; their jobs run first (`ADMIN_PRIORITY`).
- Operators queue only the types that carry an `OperatorRule` (fine-tuning and anchor proposals
  on a sequence they work on, the selftest), within the rule's bounds: a numeric param above its
  bound, or an admin-only switch turned on (finetune's `predict`), is refused with 403 naming
  the param.
- Per user, at most `job_max_queued_per_user` jobs wait and `job_max_running_per_user` run at a
  time (admins included: one admin cannot fill the worker either); the queue limit is checked
  when the job is created (429), the running limit when a worker claims (the job waits).
- Each job type has a maximum run time (`JobType.max_run_seconds`, overridable per type with
  `TRACKLABEL_JOB_MAX_RUN_SECONDS='{"finetune": 600}'`); the worker stops a job past it and marks
  it failed with "exceeded its maximum run time".
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from pydantic import BaseModel
from sqlalchemy import func, or_, select
from sqlalchemy.orm import Session

from app.core.errors import Forbidden, ServiceError
from app.models import AnchorEvent, AnnotationEvent, Job, Track

if TYPE_CHECKING:
    from app.core.config import Settings
    from app.crud import AuthUser
    from app.jobs.registry import JobType

ADMIN_PRIORITY = 10
OPERATOR_PRIORITY = 0


class TooManyJobs(ServiceError):
    status_code = 429


@dataclass(frozen=True)
class OperatorRule:
    """What an operator may queue of one job type.

    `max_values`: upper bounds of numeric params (None values pass: they mean "the default").
    `admin_switches`: boolean params only an admin may turn on.
    `own_sequence`: the job's `sequence_id` must be a sequence the operator works on (they hold
    a lease there or have decided a track or an anchor of it).
    """

    max_values: Mapping[str, float] = field(default_factory=dict)
    admin_switches: tuple[str, ...] = ()
    own_sequence: bool = True


def check_operator_params(rule: OperatorRule, job_type: str, params: BaseModel) -> None:
    """Forbidden (403) naming the first param outside the operator's bounds."""
    for name in rule.admin_switches:
        if getattr(params, name, False):
            raise Forbidden(f"params.{name}: only an admin may set it on a {job_type} job")
    for name, bound in rule.max_values.items():
        value = getattr(params, name, None)
        if value is not None and value > bound:
            raise Forbidden(f"params.{name}: {value} is above the operators' limit of {bound:g} for {job_type} jobs")


def works_on(session: Session, user_id: int, sequence_id: int) -> bool:
    """True when the user holds a lease on a track of the sequence or has decided one of its
    tracks or anchors."""
    tracks = select(Track.id).where(Track.sequence_id == sequence_id)
    leased = select(Track.id).where(Track.sequence_id == sequence_id, Track.lease_user_id == user_id).limit(1)
    reviewed = select(AnnotationEvent.id).where(AnnotationEvent.user_id == user_id, AnnotationEvent.track_id.in_(tracks)).limit(1)
    anchored = select(AnchorEvent.id).where(AnchorEvent.user_id == user_id, AnchorEvent.sequence_id == sequence_id).limit(1)
    return any(session.scalar(q) is not None for q in (leased, reviewed, anchored))


def authorize(session: Session, user: AuthUser, job_type: JobType, params: BaseModel, settings: Settings) -> int:
    """Check that `user` may queue `job_type` with `params` now; returns the job's priority.

    Forbidden (403) for a type or params beyond the caller's role, TooManyJobs (429) past the
    per-user queue limit."""
    if not user.is_admin:
        rule = job_type.rule_for_operators()
        if rule is None:
            raise Forbidden(f"job type {job_type.name!r} needs the admin role")
        check_operator_params(rule, job_type.name, params)
        sequence_id = getattr(params, "sequence_id", None)
        if rule.own_sequence and sequence_id is not None and not works_on(session, user.id, sequence_id):
            raise Forbidden(f"sequence {sequence_id}: operators queue {job_type.name} jobs only on sequences they review")
    queued = session.scalar(
        select(func.count()).select_from(Job).where(Job.created_by_id == user.id, Job.status == "queued")
    ) or 0
    if queued >= settings.job_max_queued_per_user:
        raise TooManyJobs(
            f"{user.name} has {queued} queued jobs (limit {settings.job_max_queued_per_user}); wait or cancel one"
        )
    return ADMIN_PRIORITY if user.is_admin else OPERATOR_PRIORITY


def max_run_seconds(job_type: JobType, settings: Settings) -> float:
    """The run-time limit of a job type (the settings' override first)."""
    return float(settings.job_max_run_seconds.get(job_type.name, job_type.max_run_seconds))


def users_at_running_limit(session: Session, limit: int) -> Any:
    """SQL: ids of users who already have `limit` running jobs (their queued jobs wait)."""
    return (
        select(Job.created_by_id)
        .where(Job.status == "running", Job.created_by_id.is_not(None))
        .group_by(Job.created_by_id)
        .having(func.count() >= limit)
    )


def claimable_owner(session: Session, limit: int) -> Any:
    """SQL condition on a queued job: its owner is below the running limit."""
    return or_(Job.created_by_id.is_(None), Job.created_by_id.not_in(users_at_running_limit(session, limit)))


def describe(job_type: JobType, settings: Settings) -> dict[str, Any]:
    """Who may queue the type and within which bounds (for `GET /job-types`)."""
    rule = job_type.rule_for_operators()
    return {
        "operators_may_queue": rule is not None,
        "operator_max_values": dict(rule.max_values) if rule else {},
        "admin_only_params": list(rule.admin_switches) if rule else [],
        "max_run_seconds": max_run_seconds(job_type, settings),
    }
