"""Query strings as strict as bodies: a parameter the route does not declare, or a repeated one
the route takes once, is a 422 (naming it), not silently ignored. (FastAPI ignores both; the
OpenAPI contract says they are not part of the request.) A NUL byte in a query or path value is
a 422 too (PostgreSQL cannot hold one: `/models?kind=car%00` was a 500)."""

from __future__ import annotations

from fastapi import Request
from fastapi.dependencies.models import Dependant
from fastapi.exceptions import RequestValidationError
from fastapi.routing import APIRoute
from pydantic.fields import FieldInfo

_DECLARED: dict[int, tuple[frozenset[str], frozenset[str]]] = {}


def _declared(route: APIRoute) -> tuple[frozenset[str], frozenset[str]]:
    """(every query parameter name, those that take a list) of a route, its dependencies included."""
    key = id(route)
    if key not in _DECLARED:
        params = _query_params(route.dependant)
        names = frozenset(p.alias for p in params)
        lists = frozenset(p.alias for p in params if _is_list(p.field_info))
        _DECLARED[key] = (names, lists)
    return _DECLARED[key]


def _query_params(dependant: Dependant) -> list:
    found = list(dependant.query_params)
    for sub in dependant.dependencies:
        found += _query_params(sub)
    return found


def _is_list(info: FieldInfo) -> bool:
    annotation = str(info.annotation)
    return "list[" in annotation or "List[" in annotation


async def strict_query(request: Request) -> None:
    route = request.scope.get("route")
    if not isinstance(route, APIRoute):
        return
    names, lists = _declared(route)
    errors = [
        {"loc": [where, key], "msg": "holds a NUL byte", "type": "string_pattern_mismatch"}
        for where, items in (("query", request.query_params.multi_items()), ("path", request.path_params.items()))
        for key, value in items
        if isinstance(value, str) and "\x00" in value
    ]
    for key in request.query_params:
        if key not in names:
            errors.append({"loc": ["query", key], "msg": "not a parameter of this operation", "type": "extra_forbidden"})
        elif key not in lists and len(request.query_params.getlist(key)) > 1:
            errors.append({"loc": ["query", key], "msg": "given more than once", "type": "value_error"})
    if errors:
        raise RequestValidationError(errors)
