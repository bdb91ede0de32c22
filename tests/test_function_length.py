"""No function over 80 lines outside numba kernels: a long function becomes named steps."""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("pipeline", "research", "app", "annotator_ui")
MAX_LINES = 80


def _is_kernel(fn: ast.FunctionDef | ast.AsyncFunctionDef) -> bool:
    return any("njit" in ast.unparse(d) or "jit(" in ast.unparse(d) for d in fn.decorator_list)


def _long_functions() -> set[str]:
    found = set()
    for package in PACKAGES:
        for path in sorted((ROOT / package).rglob("*.py")):
            for node in ast.walk(ast.parse(path.read_text())):
                if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef) and not _is_kernel(node):
                    if node.end_lineno - node.lineno + 1 > MAX_LINES:
                        found.add(f"{path.relative_to(ROOT).as_posix()}:{node.name}")
    return found


def test_function_length_none_over_80_lines():
    assert _long_functions() == set(), "split these into named steps"
