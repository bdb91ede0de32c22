"""Every error the API returns has one of two documented shapes:

- `ErrorBody` `{"detail": "<message>", ...}` for 401, 403, 404, 409, 413 and 429 (a few add fields,
  e.g. a duplicate registration's `sequence_id`);
- FastAPI's `HTTPValidationError` `{"detail": [{"loc": [...], "msg": "...", "type": "..."}]}` for
  422, whether the schema refused the request or a route found it impossible (unknown class,
  frame range outside the track). The offending input is never echoed back.
"""

from __future__ import annotations

from typing import Any

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from pydantic import BaseModel, ConfigDict, ValidationError
from starlette.exceptions import HTTPException as StarletteHTTPException

from app.api.redact import hide_paths
from app.artifacts import ArtifactMissing
from app.core.errors import Invalid, ServiceError


class ErrorBody(BaseModel):
    """The body of every 4xx error but 422."""

    model_config = ConfigDict(extra="allow")
    detail: str


def _items(errors: list[Any], prefix: tuple[str, ...] = ()) -> list[dict[str, Any]]:
    """Validation errors without their input (which may be megabytes) or context."""
    return [
        {"loc": [*prefix, *(e.get("loc") or ())], "msg": str(e.get("msg", "")), "type": str(e.get("type", "value_error"))}
        for e in errors
    ]


def invalid_body(message: str) -> dict[str, Any]:
    return {"detail": [{"loc": [], "msg": message, "type": "value_error"}]}


def allowed_methods(request: Request) -> list[str]:
    """Every method the API documents at the request's path (the `Allow` of a 405)."""
    from starlette.routing import compile_path

    patterns = getattr(request.app.state, "allow_patterns", None)
    if patterns is None:
        patterns = [(compile_path(path)[0], {m.upper() for m in item if m != "parameters"})
                    for path, item in request.app.openapi()["paths"].items()]
        request.app.state.allow_patterns = patterns
    path = request.url.path
    return sorted({m for regex, methods in patterns if regex.match(path) for m in methods})


def install(app: FastAPI) -> None:
    """Register the handlers that give every error its documented shape."""

    @app.exception_handler(Invalid)
    async def _invalid(_request: Request, exc: Invalid) -> JSONResponse:
        return JSONResponse({**invalid_body(exc.detail), **exc.extra}, status_code=422)

    @app.exception_handler(ServiceError)
    async def _service_error(_request: Request, exc: ServiceError) -> JSONResponse:
        return JSONResponse({"detail": exc.detail, **exc.extra}, status_code=exc.status_code)

    @app.exception_handler(ArtifactMissing)
    async def _artifact_missing(_request: Request, exc: ArtifactMissing) -> JSONResponse:
        return JSONResponse({"detail": hide_paths(str(exc))}, status_code=404)

    @app.exception_handler(StarletteHTTPException)
    async def _http_error(request: Request, exc: StarletteHTTPException) -> JSONResponse:
        if exc.status_code == 400:  # FastAPI's "error parsing the body": a malformed body is a 422 too
            return JSONResponse({"detail": [{"loc": ["body"], "msg": "the body is not valid JSON", "type": "json_invalid"}]},
                                status_code=422)
        headers = exc.headers
        if exc.status_code == 405:  # Starlette names only the first route of the path's methods
            headers = {**(headers or {}), "Allow": ", ".join(allowed_methods(request) or [(exc.headers or {}).get("Allow", "")])}
        return JSONResponse({"detail": exc.detail}, status_code=exc.status_code, headers=headers)

    @app.exception_handler(RequestValidationError)
    async def _request_invalid(_request: Request, exc: RequestValidationError) -> JSONResponse:
        return JSONResponse({"detail": _items(list(exc.errors()))}, status_code=422)

    @app.exception_handler(ValidationError)
    async def _validation_error(_request: Request, exc: ValidationError) -> JSONResponse:
        # a model validated inside a route (job params, config) is the caller's error, not ours
        return JSONResponse({"detail": _items(exc.errors(include_url=False, include_context=False))}, status_code=422)
