"""Job policy: who may queue what, with which parameters, how many at a time, and in which order.

- Admins queue every job type with any valid params; their jobs run first (`ADMIN_PRIORITY`).
- Operators queue only the types that carry an `OperatorRule` (fine-tuning and anchor proposals
  on a sequence an admin assigned them to, the selftest), within the rule's bounds: every numeric
  param but the ids has one (`max_values`); a value above it, a null where it applies (null
  meant "no limit": `steps_per_epoch: null` is one pass over all pairs), or an admin-only switch
  turned on (finetune's `predict`) is refused with 403 naming the param.
- For everyone, `threads` may not exceed this machine's cores (422); a worker with fewer cores
  runs the job with its own count.
- Per user, at most `job_max_queued_per_user` jobs wait and `job_max_running_per_user` run at a
  time (admins included: one admin cannot fill the worker either); the queue limit is checked
  when the job is created (429), the running limit when a worker claims (the job waits).
- Each job type has a maximum run time (`JobType.max_run_seconds`, overridable per type with
  `TRACKLABEL_JOB_MAX_RUN_SECONDS='{"finetune": 600}'`); the worker stops a job past it and marks
  it failed with "exceeded its maximum run time".
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from pydantic import BaseModel
from sqlalchemy.orm import Session

from app.core.errors import Forbidden, Invalid, ServiceError
from app.crud.assignments import is_assigned
from app.crud.jobs import queued_count

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

    `max_values`: upper bounds of numeric params; a null value where a bound applies is refused.
    `admin_switches`: boolean params only an admin may turn on.
    `own_sequence`: the job's `sequence_id` must be a sequence an admin assigned the operator to
    (`POST /assignments`; leases and reviews alone do not count).
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
        if value is None:
            raise Forbidden(f"params.{name}: operators give a value of at most {bound:g} for {job_type} jobs (null means no limit)")
        if value > bound:
            raise Forbidden(f"params.{name}: {value} is above the operators' limit of {bound:g} for {job_type} jobs")


def machine_cores() -> int:
    """CPU cores this process may use."""
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        return os.cpu_count() or 1


def check_threads(params: BaseModel) -> None:
    """Invalid (422) when a `threads` param asks for more cores than the machine has (anyone)."""
    threads = getattr(params, "threads", None)
    if threads is not None and threads > machine_cores():
        raise Invalid(f"params.threads: {threads} is more than this machine's {machine_cores()} cores")


def authorize(session: Session, user: AuthUser, job_type: JobType, params: BaseModel, settings: Settings) -> int:
    """Check that `user` may queue `job_type` with `params` now; returns the job's priority.

    Forbidden (403) for a type or params beyond the caller's role, Invalid (422) for more threads
    than cores, TooManyJobs (429) past the per-user queue limit."""
    if not user.is_admin:
        rule = job_type.rule_for_operators()
        if rule is None:
            raise Forbidden(f"job type {job_type.name!r} needs the admin role")
        check_operator_params(rule, job_type.name, params)
        sequence_id = getattr(params, "sequence_id", None)
        if rule.own_sequence and sequence_id is not None and not is_assigned(session, user.id, sequence_id):
            raise Forbidden(
                f"sequence {sequence_id}: operators queue {job_type.name} jobs only on sequences an admin assigned them to"
            )
    check_threads(params)
    queued = queued_count(session, user.id)
    if queued >= settings.job_max_queued_per_user:
        raise TooManyJobs(
            f"{user.name} has {queued} queued jobs (limit {settings.job_max_queued_per_user}); wait or cancel one"
        )
    return ADMIN_PRIORITY if user.is_admin else OPERATOR_PRIORITY


def max_run_seconds(job_type: JobType, settings: Settings) -> float:
    """The run-time limit of a job type (the settings' override first)."""
    return float(settings.job_max_run_seconds.get(job_type.name, job_type.max_run_seconds))


def describe(job_type: JobType, settings: Settings) -> dict[str, Any]:
    """Who may queue the type and within which bounds (for `GET /job-types`)."""
    rule = job_type.rule_for_operators()
    return {
        "operators_may_queue": rule is not None,
        "operator_max_values": dict(rule.max_values) if rule else {},
        "admin_only_params": list(rule.admin_switches) if rule else [],
        "max_run_seconds": max_run_seconds(job_type, settings),
    }
