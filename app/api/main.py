"""The `/api/v1` router: one sub-router per resource."""

from __future__ import annotations

from fastapi import APIRouter

from app.api.routes import (
    anchors,
    datasets,
    exports,
    frames,
    health,
    jobs,
    models,
    repair,
    review,
    stitches,
    tracks,
    users,
)

api_router = APIRouter()
for module in (health, users, datasets, frames, tracks, repair, review, exports, jobs, models, anchors, stitches):
    api_router.include_router(module.router)
