"""Types and base models every schema module shares: the request base (strict JSON kinds, no NUL bytes), the public base (from table rows), UTC datetimes."""

from __future__ import annotations

from datetime import UTC, datetime
from types import UnionType
from typing import Annotated, Any, Literal, Union, get_args, get_origin

from pydantic import AfterValidator, BaseModel, ConfigDict, model_validator

from pipeline.label_sets.model import Name

Role = Literal["operator", "reviewer", "admin"]
TrackStatus = Literal["pending", "accepted", "discarded", "merged"]
JobStatus = Literal["queued", "running", "succeeded", "failed", "cancelled"]
SequenceStatus = Literal["registered", "ingesting", "ready", "failed"]
# A class of the sequence's label set (pipeline/label_sets): the set differs per sequence, so the
# schema checks the form of a class name and the route checks it against the set (422 naming both)
ClassName = Name
LabelSource = Literal["review", "bulk"]


def _as_utc(value: datetime) -> datetime:
    """The tables hold naive UTC (app.models.utcnow); the API says so: RFC 3339 with `Z`."""
    return value.replace(tzinfo=UTC) if value.tzinfo is None else value.astimezone(UTC)


UtcDateTime = Annotated[datetime, AfterValidator(_as_utc)]


class _Public(BaseModel):
    model_config = ConfigDict(from_attributes=True)


class JsonModel(BaseModel):
    """A request body (or job params) read as JSON Schema reads it: a number field takes a JSON
    number only, an integer field a number without fraction (`1` or `1.0`: JSON Schema counts
    `1.0` an integer, and refusing it would break the declared schema; `1.5` and `"1"` are 422),
    a boolean field `true` or `false` only. Pydantic's lax mode would coerce `"1"` or `"yes"`;
    the schema promises they are refused (`{"version": "1"}` gets 422). No string field holds a
    NUL byte (PostgreSQL cannot store one; 422 instead of a 500)."""

    model_config = ConfigDict(extra="forbid")

    @model_validator(mode="before")
    @classmethod
    def _json_scalars(cls, data: Any) -> Any:
        # a model validator, not a field one: pydantic refuses field validators on the
        # discriminator fields of tagged unions (SplitRegion's `kind`)
        if not isinstance(data, dict):
            return data
        for name, value in data.items():
            if _holds_nul(value):
                raise ValueError(f"{name} holds a NUL byte")
            field = cls.model_fields.get(name)
            if field is None or value is None:
                continue
            kinds = _scalar_kinds(field.annotation)
            if bool in kinds and not isinstance(value, bool) and not kinds & {int, float}:
                raise ValueError(f"{name} must be true or false, not {type(value).__name__}")
            if kinds & {int, float} and bool not in kinds and isinstance(value, str | bool):
                raise ValueError(f"{name} must be a JSON number, not {type(value).__name__}")
        return data


def _holds_nul(value: Any) -> bool:
    """True for a string (or list of strings) with a NUL byte. Free-form JSON values (configs,
    results) may hold one: they are stored as JSON text, escaped."""
    if isinstance(value, str):
        return "\x00" in value
    return isinstance(value, list) and any(isinstance(v, str) and "\x00" in v for v in value)


# no NUL byte, and no part between slashes longer than NAME_MAX (255; a longer one is 422, not
# the file system's error). Linear to match: each repeated part must end at a slash.
PATH_PATTERN = r"^/*([^/\x00]{1,255}/+)*[^/\x00]{0,255}$"


def _scalar_kinds(annotation: Any) -> set[type]:
    """The scalar types an annotation admits (`int | None` -> {int}); empty for anything else."""
    args = get_args(annotation) if get_origin(annotation) in (Union, UnionType) else (annotation,)
    return {a for a in args if a in (int, float, bool)}


_Request = JsonModel
