"""schemathesis against the OpenAPI schema: no payload, however malformed, gets a 5xx.

Every operation in the schema is driven twice: with positive cases (valid by the schema, so they
reach the routes' own checks and the database) and with negative cases (each one breaks the
schema somewhere: wrong types, out-of-range numbers, missing or extra fields), which must get a
4xx, never a 5xx. Kept short (a few derandomised examples per operation and mode) so it runs in
seconds; it runs as an admin over a database holding an ingested sequence, so routes get past
authentication. (schemathesis' own pytest plugin does not run under this pytest, so operations
are driven here.)
"""

from __future__ import annotations

import schemathesis
from hypothesis import HealthCheck, given, settings
from hypothesis.errors import Unsatisfiable
from schemathesis import GenerationMode
from schemathesis.checks import not_a_server_error

EXAMPLES_PER_OPERATION = 6


def test_api_fuzz_never_500(client, factory):
    factory.ingested_sequence(n_frames=3, n_objects=2)
    admin = factory.user("admin")
    schema = schemathesis.openapi.from_asgi("/api/v1/openapi.json", client.app)
    failures: list[str] = []
    operations = negated = 0
    for result in schema.get_all_operations():
        operation = result.ok()
        operations += 1
        for mode in (GenerationMode.POSITIVE, GenerationMode.NEGATIVE):

            @given(case=operation.as_strategy(generation_mode=mode))
            @settings(
                max_examples=EXAMPLES_PER_OPERATION,
                deadline=None,
                derandomize=True,
                database=None,
                suppress_health_check=list(HealthCheck),
            )
            def run(case):
                case.call_and_validate(headers=admin.headers, checks=[not_a_server_error])

            try:
                run()
                negated += mode is GenerationMode.NEGATIVE
            except Unsatisfiable:
                # an operation without inputs (GET /health) has nothing to break: no negative case
                assert mode is GenerationMode.NEGATIVE, operation.path
            except Exception as exc:  # noqa: BLE001 - collect every failing operation
                failures.append(f"{mode.value} {operation.method.upper()} {operation.path}: {str(exc)[:1500]}")
    assert operations >= 25 and negated >= operations - 5  # only input-less operations lack negative cases
    assert not failures, "\n\n".join(failures)
