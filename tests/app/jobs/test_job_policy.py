"""Job policy (issue 23, defects 2 and 3): who may queue what, bounded params, per-user limits,
admins' jobs first, a maximum run time per job type."""

from __future__ import annotations

from sqlalchemy import select

from app.models import Job, utcnow
from app.worker import Worker


def _queue(client, caller, job_type, **params):
    return client.post("/api/v1/jobs", json={"type": job_type, "params": params}, headers=caller.headers)


def _model(db) -> int:
    from app.models import ModelVersion

    with db.write() as s:
        mv = ModelVersion(name="m", kind="train", path="m.pt")
        s.add(mv)
        s.commit()
        return mv.id


def _review_one(client, op):
    track = client.post("/api/v1/review/next", headers=op.headers).json()
    client.post(f"/api/v1/tracks/{track['id']}/accept", json={"version": track["version"]}, headers=op.headers)


def test_job_policy_operator_params_are_bounded(client, factory, db):
    # defect 3: epochs 1000 x steps 100000 was accepted and held the worker
    seq = factory.ingested_sequence(n_frames=3, n_objects=2)
    model_id = _model(db)
    op = factory.user("operator")
    factory.assign(op, seq)
    r = _queue(client, op, "finetune", sequence_id=seq, model_id=model_id, epochs=1000, steps_per_epoch=100000)
    assert r.status_code == 403 and "params.epochs" in r.json()["detail"]
    r = _queue(client, op, "finetune", sequence_id=seq, model_id=model_id, pairs_per_label=100)
    assert r.status_code == 403 and "params.pairs_per_label" in r.json()["detail"]
    assert _queue(client, op, "finetune", sequence_id=seq, model_id=model_id, epochs=5).status_code == 202
    admin = factory.user("admin")
    assert _queue(client, admin, "finetune", sequence_id=seq, model_id=model_id, epochs=1000).status_code == 202


def test_job_policy_operator_null_where_a_bound_applies_is_403(client, factory, db):
    # steps_per_epoch: null meant one pass over every pair, whatever the bound
    seq = factory.ingested_sequence(n_frames=3, n_objects=2)
    op = factory.user("operator")
    factory.assign(op, seq)
    r = _queue(client, op, "finetune", sequence_id=seq, model_id=_model(db), steps_per_epoch=None)
    assert r.status_code == 403 and "params.steps_per_epoch" in r.json()["detail"]


def test_job_policy_every_numeric_param_has_an_operator_bound():
    from typing import get_args

    from app.jobs.registry import job_types

    for jt in job_types():
        rule = jt.rule_for_operators()
        if rule is None or jt.operator_rule is None:
            continue
        for name, info in jt.params.model_fields.items():
            kinds = set(get_args(info.annotation)) | {info.annotation}
            if kinds & {int, float} and bool not in kinds and not name.endswith("_id"):
                assert name in rule.max_values, (jt.name, name)


def test_job_policy_threads_above_the_cores_is_422_for_everyone(client, factory, db):
    from app.jobs.policy import machine_cores

    seq = factory.ingested_sequence(n_frames=3, n_objects=2)
    admin = factory.user("admin")
    r = _queue(client, admin, "predict", sequence_id=seq, model_id=_model(db), threads=machine_cores() + 1)
    assert r.status_code == 422 and "params.threads" in r.text
    assert _queue(client, admin, "predict", sequence_id=seq, model_id=_model(db), threads=machine_cores()).status_code == 202


def test_job_policy_operator_only_on_sequences_an_admin_assigned(client, factory, db):
    seq = factory.ingested_sequence(n_frames=3, n_objects=2)
    model_id = _model(db)
    op, admin = factory.user("operator"), factory.user("admin")
    _review_one(client, op)  # a lease and a review: no right to queue jobs there
    client.post("/api/v1/review/next", headers=op.headers)
    r = _queue(client, op, "propose_anchors", sequence_id=seq, model_id=model_id)
    assert r.status_code == 403 and f"sequence {seq}" in r.json()["detail"]
    r = client.post("/api/v1/assignments", json={"sequence_id": seq, "user_id": op.id}, headers=admin.headers)
    assert r.status_code == 201, r.text
    assert _queue(client, op, "propose_anchors", sequence_id=seq, model_id=model_id).status_code == 202
    assert client.get("/api/v1/assignments", headers=op.headers).json()[0]["sequence_id"] == seq
    assert client.post("/api/v1/assignments", json={"sequence_id": seq, "user_id": op.id},
                       headers=admin.headers).status_code == 409
    assert client.post("/api/v1/assignments", json={"sequence_id": seq, "user_id": op.id},
                       headers=op.headers).status_code == 403
    assert client.delete(f"/api/v1/assignments/{r.json()['id']}", headers=admin.headers).status_code == 204
    assert _queue(client, op, "propose_anchors", sequence_id=seq, model_id=model_id).status_code == 403


def test_job_policy_operator_cannot_queue_admin_types(client, factory):
    seq = factory.ingested_sequence(n_frames=3, n_objects=2)
    op = factory.user("operator")
    for job_type, params in (("predict", {"sequence_id": seq, "model_id": 1}), ("train", {"sequence_ids": [seq]})):
        assert _queue(client, op, job_type, **params).status_code == 403, job_type


def test_job_policy_per_user_queue_limit_is_429(client, factory, settings):
    op = factory.user("operator")
    for _ in range(settings.job_max_queued_per_user):
        assert _queue(client, op, "selftest").status_code == 202
    r = _queue(client, op, "selftest")
    assert r.status_code == 429 and "limit" in r.json()["detail"]
    other = factory.user("operator")
    assert _queue(client, other, "selftest").status_code == 202


def test_job_policy_admin_jobs_run_first(client, factory, settings, db):
    op, admin = factory.user("operator"), factory.user("admin")
    first = _queue(client, op, "selftest", steps=1, step_seconds=0).json()["id"]
    second = _queue(client, admin, "selftest", steps=1, step_seconds=0).json()["id"]
    claimed = Worker(settings, db=db).claim()
    assert claimed is not None and claimed.id == second and first < second


def test_job_policy_running_limit_holds_a_users_next_job(client, factory, settings, db):
    settings.job_max_running_per_user = 1
    busy, other = factory.user("operator"), factory.user("operator")
    running = _queue(client, busy, "selftest").json()["id"]
    waiting = _queue(client, busy, "selftest").json()["id"]
    later = _queue(client, other, "selftest").json()["id"]
    with db.write() as s:
        job = s.get(Job, running)
        job.status, job.worker_id, job.lease_expires_at = "running", "elsewhere", utcnow().replace(year=2100)
        s.commit()
    claimed = Worker(settings, db=db).claim()
    assert claimed is not None and claimed.id == later and waiting < later


def test_job_policy_max_run_time_stops_and_marks_the_job(client, factory, settings, db):
    settings.job_max_run_seconds = {"selftest": 0.3}
    op = factory.user("operator")
    job_id = _queue(client, op, "selftest", steps=100, step_seconds=0.05).json()["id"]
    assert Worker(settings, db=db).run_once()
    body = client.get(f"/api/v1/jobs/{job_id}", headers=op.headers).json()
    assert body["status"] == "failed" and "maximum run time" in body["error"] and body["progress"] < 1.0


def test_job_policy_operators_see_no_traceback_or_paths(client, factory, db):
    # defect 11: a failed job showed operators a traceback with server paths
    op, admin = factory.user("operator"), factory.user("admin")
    job_id = _queue(client, op, "selftest").json()["id"]
    error = 'FileNotFoundError: /srv/data/seq/velodyne/000001.bin\nTraceback (most recent call last):\n  File "/opt/app/worker.py"'
    with db.write() as s:
        job = s.scalars(select(Job).where(Job.id == job_id)).one()
        job.status, job.error, job.result = "failed", error, {"path": "/srv/models/ckpt.pt"}
        s.commit()
    seen = client.get(f"/api/v1/jobs/{job_id}", headers=op.headers).json()
    assert seen["error"] == "FileNotFoundError: <path>" and seen["result"] == {"path": "<path>"}
    assert client.get(f"/api/v1/jobs/{job_id}", headers=admin.headers).json()["error"] == error
    listed = client.get("/api/v1/jobs", headers=op.headers).json()
    assert all("Traceback" not in (j["error"] or "") for j in listed)
