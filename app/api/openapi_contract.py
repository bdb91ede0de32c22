"""The OpenAPI document says exactly what the service accepts.

- Integer bounds print as integers: FastAPI's OpenAPI models hold `maximum` as a float, so
  `le=2**62` came out as `4.611686018427388e+18` (which is not 2**62) and `le=10` as `10.0`.
- A free-text string of a request (parameter or body) says that it takes no NUL byte
  (`pattern: ^[^\\x00]*$`): the service refuses one with 422 (app/schemas.py,
  app/api/query_check.py), since PostgreSQL cannot store it.
"""

from __future__ import annotations

from typing import Any

NO_NUL = "^[^\\x00]*$"
_BOUNDS = ("minimum", "maximum", "exclusiveMinimum", "exclusiveMaximum")


def tighten(doc: dict[str, Any]) -> dict[str, Any]:
    """`doc` with integral bounds of integer schemas as ints, and NUL refused in the free strings
    of requests (parameters and bodies; a 422 may name a refused key as it came) (in place)."""
    _walk(doc, _int_bounds)
    for schema in _request_schemas(doc):
        _walk(schema, _no_nul)
    return doc


def _int_bounds(node: dict[str, Any]) -> None:
    if node.get("type") == "integer":
        for key in _BOUNDS:
            value = node.get(key)
            if isinstance(value, float) and value.is_integer():
                node[key] = int(value)


def _no_nul(node: dict[str, Any]) -> None:
    if node.get("type") == "string" and not {"enum", "const", "pattern", "format"} & set(node):
        node["pattern"] = NO_NUL


def _request_schemas(doc: dict[str, Any]) -> list[dict[str, Any]]:
    """The schemas of every parameter and request body, with the components they refer to."""
    roots: list[Any] = []
    for item in doc.get("paths", {}).values():
        for op in item.values():
            if not isinstance(op, dict):
                continue
            roots += [p.get("schema", {}) for p in op.get("parameters", [])]
            roots += [c.get("schema", {}) for c in op.get("requestBody", {}).get("content", {}).values()]
    components = doc.get("components", {}).get("schemas", {})
    seen: set[str] = set()
    todo = list(roots)
    while todo:
        node = todo.pop()
        for ref in _refs(node):
            name = ref.rsplit("/", 1)[-1]
            if name not in seen and name in components:
                seen.add(name)
                todo.append(components[name])
    return roots + [components[name] for name in sorted(seen)]


def _refs(node: Any) -> list[str]:
    if isinstance(node, list):
        return [r for item in node for r in _refs(item)]
    if not isinstance(node, dict):
        return []
    here = [node["$ref"]] if isinstance(node.get("$ref"), str) else []
    return here + [r for value in node.values() for r in _refs(value)]


def _walk(node: Any, visit: Any) -> None:
    if isinstance(node, list):
        for item in node:
            _walk(item, visit)
        return
    if not isinstance(node, dict):
        return
    visit(node)
    for value in node.values():
        _walk(value, visit)
