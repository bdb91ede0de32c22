"""Trained models: `GET /models` (newest first, with a metrics summary), `GET /models/{id}` (all
stored metrics and the config) and `GET /models/{id}/plots/{name}` (the learning curve and the
validation confusion matrix as PNG). Models are registered by the `train` / `finetune` jobs."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any, Literal

from fastapi import APIRouter, Query
from fastapi.responses import FileResponse
from pydantic import BaseModel, ConfigDict, Field

from app.api.deps import CurrentUser, IdPath, SessionDep
from app.api.redact import hide_paths_in
from app.core.errors import NotFound
from app.crud import AuthUser, model_versions
from app.models import ModelVersion
from app.schemas import UtcDateTime

router = APIRouter(tags=["models"])


class ModelSummary(BaseModel):
    model_config = ConfigDict(from_attributes=True)

    id: int
    name: str
    kind: str
    path: str | None = Field(description="The checkpoint on the server (admins only).")
    parent_id: int | None
    job_id: int | None
    created_by_id: int | None
    created_at: UtcDateTime
    val_mean_f: float | None = None
    val_f: dict[str, float | None] | None = None
    num_labelled: int | None = None
    num_pairs: int | None = None


class ModelDetail(ModelSummary):
    metrics: dict[str, Any] | None
    config: dict[str, Any] | None


def _summary_fields(mv: ModelVersion) -> dict[str, Any]:
    m = mv.metrics or {}
    val = m.get("val") if isinstance(m.get("val"), dict) else {}
    per_class = val.get("per_class") if isinstance(val.get("per_class"), dict) else None
    val_f = None
    if per_class is not None:
        val_f = {c: (v.get("f") if isinstance(v, dict) else None) for c, v in per_class.items()}
    return {
        "val_mean_f": val.get("mean_f"),
        "val_f": val_f,
        "num_labelled": m.get("num_labelled"),
        "num_pairs": m.get("num_pairs"),
    }


def _summary(mv: ModelVersion, user: AuthUser) -> ModelSummary:
    return ModelSummary.model_validate(mv).model_copy(update=_summary_fields(mv) | _hidden(user))


def _hidden(user: AuthUser) -> dict[str, Any]:
    """What operators do not see: the checkpoint's server path (defect 11 of issue 23)."""
    return {} if user.is_admin else {"path": None}


@router.get("/models")
def list_models(
    user: CurrentUser,
    session: SessionDep,
    kind: Annotated[str | None, Query(max_length=32)] = None,
    limit: Annotated[int, Query(ge=1, le=1000)] = 100,
    offset: Annotated[int, Query(ge=0, le=2**31 - 1)] = 0,
) -> list[ModelSummary]:
    """Registered models, newest first, each with its validation F (mean and per class)."""
    return [_summary(mv, user) for mv in model_versions.list_model_versions(session, kind, limit, offset)]


@router.get("/models/{model_id}")
def get_model(model_id: IdPath, user: CurrentUser, session: SessionDep) -> ModelDetail:
    """One model with all its stored metrics and the config it was trained with; 404 when unknown."""
    mv = model_versions.get_model_version(session, model_id)
    detail = ModelDetail.model_validate(mv).model_copy(update=_summary_fields(mv) | _hidden(user))
    if not user.is_admin:
        detail = detail.model_copy(update={"metrics": hide_paths_in(detail.metrics), "config": hide_paths_in(detail.config)})
    return detail


@router.get("/models/{model_id}/plots/{name}", response_class=FileResponse,
            responses={200: {"content": {"image/png": {}}}, 404: {"description": "unknown model or no such plot"}})
def get_model_plot(
    model_id: IdPath, name: Literal["learning_curve.png", "confusion.png"], _user: CurrentUser, session: SessionDep
) -> FileResponse:
    """A PNG written beside the model's checkpoint when it was trained: `learning_curve.png` (loss
    and validation F per epoch) or `confusion.png` (validation confusion of the selected epoch)."""
    mv = model_versions.get_model_version(session, model_id)
    path = Path(mv.path).parent / name
    if not path.is_file():
        raise NotFound(f"model {model_id} has no {name}")
    return FileResponse(path, media_type="image/png")
