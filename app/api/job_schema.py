"""The OpenAPI body of `POST /jobs`, built from the job-type registry when the schema is served:
one object per type, `{"type": <name>, "params": <that type's params>}`, joined by `oneOf` with
`type` as the discriminator. The route validates the same way (app/api/routes/jobs.py), so the
schema promises exactly what is accepted, plugins' types (TRACKLABEL_JOB_MODULES) included."""

from __future__ import annotations

from typing import Annotated, Any, Literal, Union

from pydantic import BaseModel, ConfigDict, Field, TypeAdapter, create_model

from app.jobs.registry import JobType

REF = "#/components/schemas/{model}"


def _request_model(jt: JobType) -> type[BaseModel]:
    required = any(f.is_required() for f in jt.params.model_fields.values())
    params: Any = (jt.params, ...) if required else (jt.params, Field(default_factory=jt.params))
    name = "".join(p.capitalize() for p in jt.name.split("_")) + "JobCreate"
    return create_model(name, __config__=ConfigDict(extra="forbid"), type=(Literal[jt.name], ...), params=params)


def job_create_schema(types: list[JobType]) -> tuple[dict[str, Any], dict[str, Any]]:
    """(the body schema, the component schemas it refers to)."""
    models = tuple(_request_model(jt) for jt in types)
    union = models[0] if len(models) == 1 else Annotated[Union[models], Field(discriminator="type")]  # noqa: UP007
    schema = TypeAdapter(union).json_schema(ref_template=REF)
    defs = schema.pop("$defs", {})
    return schema, defs


def patch_openapi(openapi: dict[str, Any], path: str, types: list[JobType]) -> dict[str, Any]:
    """Put the per-type body schema on `POST path` of a generated OpenAPI document (in place)."""
    schema, defs = job_create_schema(types)
    components = openapi.setdefault("components", {}).setdefault("schemas", {})
    components.update(defs)
    components["JobCreate"] = schema
    body = openapi["paths"][path]["post"]["requestBody"]["content"]["application/json"]
    body["schema"] = {"$ref": "#/components/schemas/JobCreate"}
    return openapi
