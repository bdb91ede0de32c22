"""The quality stage (issue 23): admins and reviewers sample accepted tracks into an audit queue
and agree with or correct each; agreement per operator and class is in `/exports/stats`."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Query, status

from app.api.deps import AuditorUser, IdPath, LeaseGuardDep, SessionDep, WriteSessionDep
from app.core.errors import Forbidden
from app.crud import audits
from app.schemas import AuditCorrect, AuditPublic, AuditSample, AuditStatus

router = APIRouter(tags=["audits"])


@router.post("/audits/sample", status_code=status.HTTP_201_CREATED)
def sample(body: AuditSample, user: AuditorUser, session: WriteSessionDep) -> list[AuditPublic]:
    """Queue `n` accepted tracks that were never audited, drawn at random with `seed` (admin or
    reviewer); with `source` only tracks whose class came from it (`bulk`: the measured error of
    bulk accepts per class, with its confidence interval, is in `/exports/stats` under `audits.bulk`)."""
    picked = audits.sample_audits(session, user, body.n, body.sequence_id, body.seed, body.source)
    return [AuditPublic.model_validate(a) for a in picked]


@router.get("/audits")
def list_audits(
    _user: AuditorUser,
    session: SessionDep,
    status: AuditStatus | None = None,
    sequence_id: Annotated[int | None, Query(ge=1, le=2**31 - 1)] = None,
    limit: Annotated[int, Query(ge=1, le=1000)] = 100,
    offset: Annotated[int, Query(ge=0, le=2**31 - 1)] = 0,
) -> list[AuditPublic]:
    """Audits, oldest first (admin or reviewer)."""
    return [AuditPublic.model_validate(a) for a in audits.list_audits(session, status, sequence_id, limit, offset)]


def _decide(audit_id: int, guard: LeaseGuardDep, session: WriteSessionDep, label: str | None) -> AuditPublic:
    if guard.user.role not in ("admin", "reviewer"):
        raise Forbidden("admin or reviewer role required")
    audit = audits.decide_audit(session, audit_id, guard.user, label, guard.override, guard.lease_seconds)
    return AuditPublic.model_validate(audit)


@router.post("/audits/{audit_id}/agree")
def agree(audit_id: IdPath, guard: LeaseGuardDep, session: WriteSessionDep) -> AuditPublic:
    """The operator's class is right. 409 when already decided or the track is no longer accepted."""
    return _decide(audit_id, guard, session, None)


@router.post("/audits/{audit_id}/correct")
def correct(audit_id: IdPath, body: AuditCorrect, guard: LeaseGuardDep, session: WriteSessionDep) -> AuditPublic:
    """The track's class is `label`: it is relabelled (an event of the auditor) and the audit
    counts as a disagreement unless `label` is the operator's class."""
    return _decide(audit_id, guard, session, body.label)


@router.post("/audits/{audit_id}/discard")
def discard(audit_id: IdPath, guard: LeaseGuardDep, session: WriteSessionDep) -> AuditPublic:
    """The track is no object of any class (ground, noise): it is discarded (an event of the
    auditor) and the audit counts as corrected. 409 when already decided or no longer accepted."""
    return _decide(audit_id, guard, session, audits.DISCARD)
