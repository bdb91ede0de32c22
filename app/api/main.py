"""The `/api/v1` router: one sub-router per resource, every error status each route can answer
declared in the OpenAPI schema (with the body shapes of app/api/errors.py)."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter, Depends
from fastapi.dependencies.models import Dependant
from fastapi.routing import APIRoute

from app.api import deps, retry
from app.api.errors import ErrorBody
from app.api.query_check import strict_query
from app.api.routes import (
    anchors,
    assignments,
    audits,
    bulk,
    changes,
    datasets,
    exports,
    frames,
    ground_regions,
    health,
    jobs,
    models,
    repair,
    review,
    stitches,
    tracks,
    users,
)

ERROR_TEXT = {
    401: "Missing, invalid, expired or revoked token, or a disabled user.",
    403: "The caller's role may not do this.",
    404: "An id in the path, query or body names nothing.",
    409: "The state does not allow it (stale version, another user's lease, not ready, a duplicate).",
    413: "The request body is larger than the service's max_body_bytes.",
    429: "Too many invalid tokens from the client's address (Retry-After says how long to wait).",
}
# which dependencies can refuse a caller's role (403)
_ROLE_CHECKS = {deps.require_admin, deps.require_auditor, deps.get_lease_guard}


def _calls(dependant: Dependant) -> set[Any]:
    found = {dependant.call}
    for sub in dependant.dependencies:
        found |= _calls(sub)
    return found


def error_statuses(route: APIRoute) -> list[int]:
    """The 4xx (but 422, which FastAPI declares) a route can answer."""
    calls = _calls(route.dependant)
    if deps.get_current_user not in calls:
        return []
    codes = [401]
    if calls & _ROLE_CHECKS or route.methods & {"POST"}:
        codes.append(403)
    if route.dependant.path_params or route.dependant.query_params or route.body_field is not None:
        codes.append(404)
    if route.methods & {"POST"}:
        codes.append(409)
    if route.body_field is not None:
        codes.append(413)
    codes.append(429)
    return codes


def declare_errors(router: APIRouter) -> None:
    """Add each route's error statuses to its OpenAPI responses (kept where a route says more)."""
    for route in router.routes:
        if isinstance(route, APIRoute):
            for code in error_statuses(route):
                entry = route.responses.setdefault(code, {})
                entry.setdefault("description", ERROR_TEXT[code])
                entry.setdefault("model", ErrorBody)


api_router = APIRouter(dependencies=[Depends(strict_query)])
for module in (health, users, datasets, assignments, frames, tracks, repair, review, bulk, exports, jobs, models, anchors,
               stitches, audits, changes, ground_regions):
    declare_errors(module.router)  # before including: an included router's routes are not listed
    retry.install(module.router)  # a route that loses a race to another writer runs again
    api_router.include_router(module.router)
