from __future__ import annotations

from fastapi import APIRouter

from app.api.deps import DatabaseDep
from app.schemas import Health

router = APIRouter(tags=["health"])


@router.get("/health")
def health(db: DatabaseDep) -> Health:
    """Liveness and database reachability (no token needed)."""
    from pipeline import __version__

    db.ping()
    return Health(status="ok", database=db.dialect, version=__version__)
