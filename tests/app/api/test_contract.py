"""The strict contract (issue 23, defect 12): time zones, one error shape, declared statuses,
enums, strict integers; each reproduced as the audit reported it."""

from __future__ import annotations

from datetime import datetime


def _openapi(client):
    return client.get("/api/v1/openapi.json").json()


def test_contract_timestamps_carry_a_time_zone(client, factory):
    op = factory.user("operator")
    created = client.get("/api/v1/users/me", headers=op.headers).json()["created_at"]
    assert datetime.fromisoformat(created).utcoffset() is not None, created


def test_contract_422_detail_is_always_a_list(client, factory):
    op = factory.user("operator")
    # a route's own check (job params) and a schema check (a missing field) give the same shape
    for body in ({"type": "selftest", "params": {"steps": 0}}, {"params": {}}):
        r = client.post("/api/v1/jobs", json=body, headers=op.headers)
        assert r.status_code == 422 and isinstance(r.json()["detail"], list), r.text
        assert all({"loc", "msg", "type"} <= set(e) for e in r.json()["detail"])


def test_contract_422_does_not_echo_the_input(client, factory):
    op = factory.user("operator")
    marker = "x" * 5000
    r = client.post("/api/v1/tracks/1/accept", json={"version": marker}, headers=op.headers)
    assert r.status_code == 422 and marker not in r.text


def test_contract_version_must_be_a_json_integer(client, factory):
    seq = factory.ingested_sequence(n_frames=3, n_objects=1)
    op = factory.user("operator")
    track_id = client.get("/api/v1/tracks", params={"sequence_id": seq}, headers=op.headers).json()["items"][0]["id"]
    for bad in ("1", True):
        assert client.post(f"/api/v1/tracks/{track_id}/accept", json={"version": bad}, headers=op.headers).status_code == 422
    assert client.post(f"/api/v1/tracks/{track_id}/accept", json={"version": 1}, headers=op.headers).status_code == 200


def test_contract_label_is_a_class_of_the_sequence_label_set(client, factory):
    # the classes differ per sequence (its label set), so the schema checks a class name's form
    # and the route its class: a class of another set is 422 in the one list shape, naming the field
    label = _openapi(client)["components"]["schemas"]["LabelAction"]["properties"]["label"]
    assert label["type"] == "string" and "pattern" in label
    seq = factory.ingested_sequence(n_frames=3, n_objects=1)
    op = factory.user("operator")
    track = client.get("/api/v1/tracks", params={"sequence_id": seq}, headers=op.headers).json()["items"][0]
    r = client.post(f"/api/v1/tracks/{track['id']}/label", json={"version": track["version"], "label": "vehicle"},
                    headers=op.headers)
    assert r.status_code == 422 and isinstance(r.json()["detail"], list), r.text
    assert r.json()["detail"][0]["msg"].startswith("label: unknown class 'vehicle' in label set 'paper'; valid: person, car")


def test_contract_error_statuses_are_declared(client):
    paths = _openapi(client)["paths"]
    accept = paths["/api/v1/tracks/{track_id}/accept"]["post"]["responses"]
    assert {"401", "403", "404", "409", "413", "422"} <= set(accept)
    assert accept["409"]["content"]["application/json"]["schema"] == {"$ref": "#/components/schemas/ErrorBody"}
    assert "401" in paths["/api/v1/users/me"]["get"]["responses"]
    assert "429" in paths["/api/v1/jobs"]["post"]["responses"]


def test_contract_job_body_is_one_schema_per_type(client):
    doc = _openapi(client)
    body = doc["components"]["schemas"]["JobCreate"]
    assert {"finetune", "ingest", "selftest"} <= set(body["discriminator"]["mapping"])
    finetune = doc["components"]["schemas"]["FinetuneJobCreate"]["properties"]["params"]
    assert finetune == {"$ref": "#/components/schemas/FinetuneParams"}


def test_contract_unknown_or_repeated_query_parameters_are_422(client, factory):
    op = factory.user("operator")
    assert client.get("/api/v1/models", params={"kind": "train"}, headers=op.headers).status_code == 200
    for query in ("?=0", "?knd=train", "?kind=a&kind=b"):
        r = client.get(f"/api/v1/models{query}", headers=op.headers)
        assert r.status_code == 422 and isinstance(r.json()["detail"], list), query
    assert client.get("/api/v1/tracks?ids=1&ids=2", headers=op.headers).status_code == 200  # a list parameter


def test_contract_integer_fields_take_integral_numbers_only(client, factory):
    """JSON Schema's integer: 5 and 5.0 (the same number), never 5.5 nor "5"."""
    admin = factory.user("admin")
    for steps, code in ((5, 202), (5.0, 202), (5.5, 422), ("5", 422)):
        r = client.post("/api/v1/jobs", json={"type": "selftest", "params": {"steps": steps}}, headers=admin.headers)
        assert r.status_code == code, (steps, r.text)
    job = client.post("/api/v1/jobs", json={"type": "selftest", "params": {"steps": 5.0}}, headers=admin.headers).json()
    assert job["params"]["steps"] == 5 and isinstance(job["params"]["steps"], int)  # stored as the integer


def test_contract_nul_bytes_are_422_not_500(client, factory):
    admin = factory.user("admin")
    assert client.get("/api/v1/models?kind=car%00", headers=admin.headers).status_code == 422
    r = client.post("/api/v1/tokens/revoke", json={"prefix": "tl_abc\u0000def"}, headers=admin.headers)
    assert r.status_code == 422
    r = client.post("/api/v1/users", json={"name": "a\u0000b"}, headers=admin.headers)
    assert r.status_code == 422


def test_contract_integer_bounds_are_integers(client):
    schema = _openapi(client)["components"]["schemas"]["MergeAction"]["properties"]["other_track_id"]
    assert schema["maximum"] == 2**62 and isinstance(schema["maximum"], int) and isinstance(schema["minimum"], int)


def test_contract_job_times_and_messages(client, factory, settings, db):
    from app.worker import Worker

    op = factory.user("operator")
    job_id = client.post("/api/v1/jobs", json={"type": "selftest", "params": {"steps": 1}}, headers=op.headers).json()["id"]
    worker = Worker(settings, db=db)
    claimed = worker.claim()
    seen = client.get(f"/api/v1/jobs/{job_id}", headers=op.headers).json()
    assert worker.worker_id.split(":")[0] not in seen["message"] and claimed is not None
    worker.run(claimed)
    seen = client.get(f"/api/v1/jobs/{job_id}", headers=op.headers).json()
    created, started, finished = (datetime.fromisoformat(seen[k]) for k in ("created_at", "started_at", "finished_at"))
    assert created <= started <= finished
