"""The OpenAPI document says exactly what the service accepts.

- Integer bounds print as integers: FastAPI's OpenAPI models hold `maximum` as a float, so
  `le=2**62` came out as `4.611686018427388e+18` (which is not 2**62) and `le=10` as `10.0`.
- A free-text string field says that it takes no NUL byte (`pattern: ^[^\\x00]*$`): the service
  refuses one with 422 (app/schemas.py, app/api/query_check.py), since PostgreSQL cannot store it.
"""

from __future__ import annotations

from typing import Any

NO_NUL = "^[^\\x00]*$"
_BOUNDS = ("minimum", "maximum", "exclusiveMinimum", "exclusiveMaximum")


def tighten(doc: dict[str, Any]) -> dict[str, Any]:
    """`doc` with integral bounds of integer schemas as ints and NUL refused in free strings (in place)."""
    _walk(doc)
    return doc


def _walk(node: Any) -> None:
    if isinstance(node, list):
        for item in node:
            _walk(item)
        return
    if not isinstance(node, dict):
        return
    if node.get("type") == "integer":
        for key in _BOUNDS:
            value = node.get(key)
            if isinstance(value, float) and value.is_integer():
                node[key] = int(value)
    if node.get("type") == "string" and not {"enum", "const", "pattern", "format"} & set(node):
        node["pattern"] = NO_NUL
    for value in node.values():
        _walk(value)
