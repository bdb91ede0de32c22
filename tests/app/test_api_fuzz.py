"""schemathesis against the OpenAPI schema: no payload, however malformed, gets a 5xx.

Kept short (a few derandomised examples per operation) so it runs in seconds; it runs as an
admin over a database holding an ingested sequence, so routes get past authentication.
(schemathesis' own pytest plugin does not run under this pytest, so operations are driven here.)
"""

from __future__ import annotations

import schemathesis
from hypothesis import HealthCheck, given, settings
from schemathesis.checks import not_a_server_error

EXAMPLES_PER_OPERATION = 6


def test_api_fuzz_never_500(client, factory):
    factory.ingested_sequence(n_frames=3, n_objects=2)
    admin = factory.user("admin")
    schema = schemathesis.openapi.from_asgi("/api/v1/openapi.json", client.app)
    failures: list[str] = []
    operations = 0
    for result in schema.get_all_operations():
        operation = result.ok()
        operations += 1

        @given(case=operation.as_strategy())
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
        except Exception as exc:  # noqa: BLE001 - collect every failing operation
            failures.append(f"{operation.method.upper()} {operation.path}: {str(exc)[:1500]}")
    assert operations >= 25
    assert not failures, "\n\n".join(failures)
