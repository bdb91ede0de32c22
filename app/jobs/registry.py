"""The job-type registry: each type names its params model, its handler and who may start it.

Later issues add `train`, `finetune`, `predict`, `propose_anchors` by calling `register` in their
own module and listing it in `BUILTIN_MODULES` (or `TRACKLABEL_JOB_MODULES` for plugins).
"""

from __future__ import annotations

import importlib
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from pydantic import BaseModel

from app.jobs.policy import OperatorRule

if TYPE_CHECKING:
    from sqlalchemy.orm import Session

    from app.jobs.context import JobContext

BUILTIN_MODULES: tuple[str, ...] = (
    "app.jobs.ingest", "app.jobs.selftest", "app.jobs.train", "app.jobs.predict", "app.jobs.anchors", "app.jobs.finetune",
    "app.jobs.assist",
)


@dataclass(frozen=True)
class JobType:
    """A kind of job.

    handler(ctx, params) -> result dict; it calls `ctx.progress(...)` at checkpoints.
    on_stop(ctx, params, reason) runs when the handler raised or was cancelled ("failed"/"cancelled").
    operator_rule: what operators may queue (app.jobs.policy); None with admin_only = admins only.
    max_run_seconds: the worker stops a job running longer and marks it failed.
    prepare(session, params) runs when the job is created, inside that transaction: it checks what
    the job needs (raising app.core.errors.ServiceError) and may mark rows (e.g. the sequence).
    """

    name: str
    params: type[BaseModel]
    handler: Callable[[JobContext, Any], dict[str, Any]]
    admin_only: bool = True
    description: str = ""
    on_stop: Callable[[JobContext, Any, str], None] | None = None
    prepare: Callable[[Session, Any], None] | None = None
    operator_rule: OperatorRule | None = None
    max_run_seconds: float = 6 * 3600.0

    def rule_for_operators(self) -> OperatorRule | None:
        """The operators' rule: the declared one, an unbounded one for a type that is not
        admin-only but declares none (plugins), None for admin-only types."""
        if self.operator_rule is not None:
            return self.operator_rule
        return None if self.admin_only else OperatorRule(own_sequence=False)


_REGISTRY: dict[str, JobType] = {}


def register(job_type: JobType) -> JobType:
    _REGISTRY[job_type.name] = job_type
    return job_type


def get_job_type(name: str) -> JobType:
    try:
        return _REGISTRY[name]
    except KeyError:
        raise KeyError(f"unknown job type {name!r}; known: {', '.join(sorted(_REGISTRY))}") from None


def job_types() -> list[JobType]:
    return [_REGISTRY[k] for k in sorted(_REGISTRY)]


def load_job_types(extra_modules: Iterable[str] = ()) -> list[str]:
    """Import the built-in job modules and any extra ones; returns the registered names."""
    for module in (*BUILTIN_MODULES, *extra_modules):
        importlib.import_module(module)
    return sorted(_REGISTRY)
