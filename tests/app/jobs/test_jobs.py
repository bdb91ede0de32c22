from __future__ import annotations

import threading
import time

from app.worker import Worker


def test_jobs_unknown_type_is_422(client, factory):
    op = factory.user()
    assert client.post("/api/v1/jobs", json={"type": "nope"}, headers=op.headers).status_code == 422


def test_jobs_bad_params_is_422(client, factory):
    op = factory.user()
    r = client.post("/api/v1/jobs", json={"type": "selftest", "params": {"steps": -1}}, headers=op.headers)
    assert r.status_code == 422


def test_jobs_operator_cannot_start_ingest(client, factory):
    op = factory.user()
    r = client.post("/api/v1/jobs", json={"type": "ingest", "params": {"sequence_id": 1}}, headers=op.headers)
    assert r.status_code == 403


def test_jobs_operator_sees_only_own_jobs(client, factory):
    a, b = factory.user(), factory.user()
    job = client.post("/api/v1/jobs", json={"type": "selftest"}, headers=a.headers).json()
    assert client.get(f"/api/v1/jobs/{job['id']}", headers=b.headers).status_code == 403
    assert client.get("/api/v1/jobs", headers=b.headers).json() == []
    assert [j["id"] for j in client.get("/api/v1/jobs", headers=a.headers).json()] == [job["id"]]


def test_jobs_operator_cannot_cancel_another_users_job(client, factory):
    a, b = factory.user(), factory.user()
    job = client.post("/api/v1/jobs", json={"type": "selftest"}, headers=a.headers).json()
    assert client.post(f"/api/v1/jobs/{job['id']}/cancel", headers=b.headers).status_code == 403
    assert client.get(f"/api/v1/jobs/{job['id']}", headers=a.headers).json()["status"] == "queued"


def test_jobs_type_registry_lists_ingest(client, factory):
    names = {t["name"] for t in client.get("/api/v1/job-types", headers=factory.user().headers).json()}
    assert {"ingest", "selftest"} <= names


def test_jobs_worker_runs_job_and_reports_result(client, factory, settings, db):
    op = factory.user()
    job = client.post("/api/v1/jobs", json={"type": "selftest", "params": {"steps": 2}}, headers=op.headers).json()
    assert Worker(settings, db=db).run_once()
    done = client.get(f"/api/v1/jobs/{job['id']}", headers=op.headers).json()
    assert (done["status"], done["progress"], done["result"]["steps"]) == ("succeeded", 1.0, 2)


def test_jobs_cancel_queued(client, factory):
    op = factory.user()
    job = client.post("/api/v1/jobs", json={"type": "selftest"}, headers=op.headers).json()
    r = client.post(f"/api/v1/jobs/{job['id']}/cancel", headers=op.headers)
    assert r.status_code == 202 and r.json()["status"] == "cancelled"
    assert r.json()["message"].endswith(f"by {op.name}")


def test_jobs_cancel_running_stops_at_checkpoint(client, factory, settings, db):
    op = factory.user()
    params = {"steps": 200, "step_seconds": 0.02}
    job = client.post("/api/v1/jobs", json={"type": "selftest", "params": params}, headers=op.headers).json()
    t = threading.Thread(target=Worker(settings, db=db).run_once)
    t.start()
    deadline = time.monotonic() + 10
    while client.get(f"/api/v1/jobs/{job['id']}", headers=op.headers).json()["progress"] == 0:
        assert time.monotonic() < deadline
        time.sleep(0.02)
    client.post(f"/api/v1/jobs/{job['id']}/cancel", headers=op.headers)
    t.join(timeout=10)
    final = client.get(f"/api/v1/jobs/{job['id']}", headers=op.headers).json()
    assert final["status"] == "cancelled" and final["progress"] < 1.0
