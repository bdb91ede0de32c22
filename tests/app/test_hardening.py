"""Defects found by the service audit (issue 23), each reproduced as it was reported."""

from __future__ import annotations

from sqlalchemy import func, select

from app.jobs import ingest
from app.models import AnnotationEvent, Job, Sequence
from app.worker import Worker
from tests.app.fakes import FakeBackend


def _run_worker_with_fake(settings, db, **kw):
    previous = ingest._backend
    ingest.set_backend(FakeBackend(**kw))
    try:
        return Worker(settings, db=db).run_once()
    finally:
        ingest.set_backend(previous)


def test_hardening_force_reingest_really_reruns(client, factory, db, settings):
    # defect 1: the forced job "succeeded" in no time and left reviews and events as they were
    admin, op = factory.user("admin"), factory.user("operator")
    seq = factory.ingested_sequence(n_frames=4, n_objects=3)
    track = client.post("/api/v1/review/next", headers=op.headers).json()
    assert client.post(f"/api/v1/tracks/{track['id']}/accept", json={"version": track["version"]},
                       headers=op.headers).status_code == 200
    r = client.post(f"/api/v1/sequences/{seq}/ingest", json={"force": True}, headers=admin.headers)
    assert r.status_code == 202
    job_id = r.json()["id"]
    assert _run_worker_with_fake(settings, db, n_frames=5, n_objects=2)
    with db.read() as s:
        job = s.get(Job, job_id)
        assert job.status == "succeeded" and job.result["frames"] == 5, job.error
        seq_row = s.get(Sequence, seq)
        assert seq_row.n_frames == 5 and seq_row.ingest_job_id == job_id
        assert s.scalar(select(func.count()).select_from(AnnotationEvent)) == 0


def test_hardening_operator_cannot_run_predict_through_finetune(client, factory):
    # defect 2: finetune's `predict: true` queued the admin-only predict job for an operator
    seq = factory.ingested_sequence(n_frames=3, n_objects=2)
    op = factory.user("operator")
    r = client.post("/api/v1/jobs", json={"type": "finetune", "params": {"sequence_id": seq, "model_id": 1, "predict": True}},
                    headers=op.headers)
    assert r.status_code == 403 and "predict" in r.json()["detail"]
