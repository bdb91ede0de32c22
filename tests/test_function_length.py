"""No function over 80 lines outside numba kernels: a long function becomes named steps.

KNOWN_LONG lists the ones not split yet; the test fails when a new one appears and when a listed
one has been split (so the list only shrinks).
"""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("pipeline", "research", "app", "annotator_ui")
MAX_LINES = 80
KNOWN_LONG = {
    "research/simulation/population.py:populate_actors",
    "pipeline/association.py:associate",
    "pipeline/pipeline.py:run_process",
    "research/simulation/simulate.py:simulate_sequence",
    "app/jobs/ingest.py:_write_frame",
    "app/crud.py:apply_action",
}


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


def test_function_length_no_new_function_over_80_lines():
    long = _long_functions()
    assert long - KNOWN_LONG == set(), "split these into named steps"
    assert KNOWN_LONG - long == set(), "split already: remove them from KNOWN_LONG"
