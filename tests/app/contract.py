"""The API contract check: schemathesis over every operation of the OpenAPI schema, with all of
its checks (server errors, status codes, content types, headers and bodies conforming to the
schema, negative data rejected, positive data accepted, auth not ignored, unsupported methods,
...), as an admin or as an operator (assigned to the sequence) over a database holding an
ingested sequence, so that routes get past authentication. Used by tests/app/api/test_api_fuzz.py (few examples) and bench/bench_service.py
(many). schemathesis' own pytest plugin does not run under this pytest, so operations are
driven here.
"""

from __future__ import annotations

from typing import Any

import schemathesis
from hypothesis import HealthCheck, given, settings
from hypothesis.errors import Unsatisfiable
from schemathesis import GenerationMode
from schemathesis.specs.openapi.checks import positive_data_acceptance


def run_contract(client: Any, factory: Any, examples: int, role: str = "admin") -> dict[str, Any]:
    """Drive every operation with `examples` positive and `examples` negative cases as a user of
    `role`; returns operations, negated (operations that had negative cases), failures and their list."""
    seq = factory.ingested_sequence(n_frames=3, n_objects=2)
    caller = factory.user(role)
    factory.assign(caller, seq)
    schema = schemathesis.openapi.from_asgi("/api/v1/openapi.json", client.app)
    failures: list[str] = []
    operations = negated = 0
    for result in schema.get_all_operations():
        operation = result.ok()
        operations += 1
        for mode in (GenerationMode.POSITIVE, GenerationMode.NEGATIVE):

            @given(case=operation.as_strategy(generation_mode=mode))
            @settings(
                max_examples=examples,
                deadline=None,
                derandomize=True,
                database=None,
                suppress_health_check=list(HealthCheck),
            )
            def run(case: Any) -> None:
                response = case.call(headers=caller.headers)
                # positive_data_acceptance judges positive cases only; a negative one is refused anyway
                refused = _label_set_refusal(response) or _cross_field_refusal(response)
                excluded = [positive_data_acceptance] if refused else None
                case.validate_response(response, headers=caller.headers, excluded_checks=excluded,
                                       transport_kwargs={"headers": dict(caller.headers)})

            try:
                run()
                negated += mode is GenerationMode.NEGATIVE
            except Unsatisfiable:
                # an operation without inputs has nothing to break: no negative case
                if mode is not GenerationMode.NEGATIVE:
                    failures.append(f"{operation.method.upper()} {operation.path}: no positive case")
            except BaseException as exc:  # noqa: BLE001 - schemathesis' FailureGroup is a BaseExceptionGroup
                if isinstance(exc, KeyboardInterrupt | SystemExit):
                    raise
                failures.append(f"{mode.value} {operation.method.upper()} {operation.path}: {str(exc)[:1500]}")
    return {"operations": operations, "negated": negated, "failures": len(failures), "failure_list": failures}


def _label_set_refusal(response: Any) -> bool:
    """A route's 422 for a class name the sequence's label set does not hold. The schema gives a
    class name's form only (each sequence has its own label set), so a schema-valid name may be
    refused; every other check still runs on such an answer."""
    return response.status_code == 422 and "unknown class" in response.text


def _cross_field_refusal(response: Any) -> bool:
    """A 422 from a rule between fields of one body (a region's z_min and z_max: both or neither,
    the bottom below the top). JSON Schema states each field's form, not such a rule, so a
    schema-valid body may break it; every other check still runs on such an answer."""
    if response.status_code != 422:
        return False
    detail = response.json().get("detail")
    return isinstance(detail, list) and bool(detail) and all(
        d.get("loc") == ["body"] and d.get("type") == "value_error" for d in detail)
