"""The FastAPI application factory: `create_app(settings)`.

Start-up order (as in full-stack-fastapi-template): wait for the database, upgrade it, seed;
`tracklabel serve` does those before building the app, and starts the job workers as separate
processes. With `embedded_worker` (off by default) the app runs one worker thread in-process
instead, for a one-process set-up whose jobs may stall its requests.
"""

from __future__ import annotations

import logging
import sys
import time
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from typing import Any

import anyio.to_thread
from fastapi import FastAPI

from app.api import errors
from app.api.body_limit import BodyLimit
from app.api.docs import install_docs
from app.api.main import api_router
from app.api.read_limit import ReadLimit
from app.api.routes import health
from app.api.security import FailedAuthLimit, SecurityHeaders
from app.artifacts import ArtifactStore
from app.core.config import Settings
from app.core.db import Database
from app.jobs.registry import load_job_types

API_PREFIX = "/api/v1"
log = logging.getLogger("tracklabel.api")


class ServerTiming:
    """ASGI middleware: `Server-Timing: app;dur=<ms>` from request start to response start."""

    def __init__(self, app: Any) -> None:
        self.app = app

    async def __call__(self, scope: dict, receive: Any, send: Any) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        t0 = time.perf_counter()

        async def timed_send(message: dict) -> None:
            if message["type"] == "http.response.start":
                dur = f"app;dur={1e3 * (time.perf_counter() - t0):.2f}".encode()
                message = {**message, "headers": [*message.get("headers", []), (b"server-timing", dur)]}
            await send(message)

        await self.app(scope, receive, timed_send)


def _serve_job_schema(app: FastAPI) -> None:
    """The OpenAPI document with `POST /jobs`'s body as one schema per registered job type."""
    from fastapi.openapi.utils import get_openapi

    from app.api.job_schema import patch_openapi
    from app.api.openapi_contract import tighten
    from app.jobs.registry import job_types

    def openapi() -> dict:
        if app.openapi_schema is None:
            doc = get_openapi(title=app.title, version=app.version, description=app.description, routes=app.routes)
            app.openapi_schema = tighten(patch_openapi(doc, f"{API_PREFIX}/jobs", job_types()))
        return app.openapi_schema

    app.openapi = openapi  # type: ignore[method-assign]


def create_app(settings: Settings | None = None, db: Database | None = None) -> FastAPI:
    """Build the API for `settings` (from the environment when None)."""
    from pipeline import __version__

    settings = settings or Settings()
    load_job_types(settings.job_modules)

    @asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        # Sync routes run in anyio's thread pool. Few threads and a short GIL switch interval keep
        # a transaction that holds the SQLite write lock from waiting behind many CPU-bound threads.
        anyio.to_thread.current_default_thread_limiter().total_tokens = settings.threadpool_size
        sys.setswitchinterval(settings.gil_switch_interval_ms / 1000)
        worker = None
        if settings.embedded_worker:
            from app.worker import Worker

            worker = Worker(settings, db=app.state.db)
            worker.start_thread()
            log.info("in-process worker %s started", worker.worker_id)
        try:
            yield
        finally:
            if worker is not None:
                worker.stop_event.set()

    app = FastAPI(
        title="tracklabel",
        version=__version__,
        description="Track-level LiDAR annotation: datasets, frames, tracks, review, exports and jobs.",
        openapi_url=f"{API_PREFIX}/openapi.json",
        docs_url=None,  # install_docs: the same page with its assets served here, not from a CDN
        redoc_url=None,
        lifespan=lifespan,
    )
    app.state.settings = settings
    # no ping before each use of a pooled connection: that round trip came on every request; a
    # connection the database dropped fails once and the request runs again (app/api/retry.py)
    app.state.db = db or Database.from_settings(settings, pre_ping=False)
    app.state.artifacts = ArtifactStore(settings.artifacts_path, payload_cache_bytes=settings.frame_cache_mb << 20)

    app.state.auth_limit = FailedAuthLimit(settings.auth_failures_per_minute)

    # inside ServerTiming, so that a read's wait for its slot is timed
    app.add_middleware(ReadLimit, limit=settings.read_concurrency,
                       exempt=("/health", f"{API_PREFIX}/health", f"{API_PREFIX}/exports"))
    app.add_middleware(BodyLimit, max_bytes=settings.max_body_bytes)
    app.add_middleware(ServerTiming)
    app.add_middleware(SecurityHeaders, docs_path=f"{API_PREFIX}/docs")  # outermost: every answer

    errors.install(app)

    app.include_router(api_router, prefix=API_PREFIX)
    _serve_job_schema(app)
    install_docs(app, API_PREFIX)
    app.include_router(health.router, include_in_schema=False)  # plain /health for load balancers
    return app
