"""Defects found by the service audit (issue 23), each reproduced as it was reported."""

from __future__ import annotations

from sqlalchemy import func, select

from app.models import AnnotationEvent, Job, Sequence
from app.worker import Worker
from tests.app.fakes import fake_pipeline


def _run_worker_with_fake(settings, db, **kw):
    with fake_pipeline(**kw):
        return Worker(settings, db=db).run_once()


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
    from tests.app.jobs.test_job_policy import _model

    seq = factory.ingested_sequence(n_frames=3, n_objects=2)
    op = factory.user("operator")
    factory.assign(op, seq)
    params = {"sequence_id": seq, "model_id": _model(factory.db), "predict": True}
    r = client.post("/api/v1/jobs", json={"type": "finetune", "params": params}, headers=op.headers)
    assert r.status_code == 403 and "predict" in r.json()["detail"]


def test_hardening_symlinked_frame_out_of_roots_is_refused_at_registration(client, factory, tmp_path):
    # defect 5: a frame file linking outside the roots was registered, ingested and served
    import os

    admin = factory.user("admin")
    folder = factory.sequence_folder("seq")
    secret = tmp_path / "secret.bin"
    secret.write_bytes(b"\0" * 16)
    os.symlink(secret, folder / "velodyne" / "000001.bin")
    r = client.post("/api/v1/datasets", json={"path": "seq"}, headers=admin.headers)
    assert r.status_code == 403 and "000001.bin" in r.json()["detail"] and str(tmp_path) not in r.json()["detail"]


def test_hardening_symlink_added_after_registration_fails_the_ingest(client, factory, db, settings, tmp_path):
    import os

    admin = factory.user("admin")
    folder = factory.sequence_folder("seq")
    r = client.post("/api/v1/datasets", json={"path": "seq"}, headers=admin.headers)
    seq = r.json()["sequences"][0]
    (tmp_path / "secret.bin").write_bytes(b"\0" * 16)
    os.symlink(tmp_path / "secret.bin", folder / "velodyne" / "000001.bin")
    assert _run_worker_with_fake(settings, db, n_frames=2, n_objects=1)
    with db.read() as s:
        job = s.get(Job, seq["ingest_job_id"])
        assert job.status == "failed" and "000001.bin" in job.error
        assert s.get(Sequence, seq["id"]).status == "failed"


def test_hardening_symlink_inside_roots_is_fine(client, factory, settings):
    import os

    admin = factory.user("admin")
    folder = factory.sequence_folder("seq")
    other = settings.data_roots[0] / "shared.bin"
    other.write_bytes(b"\0" * 16)
    os.symlink(other, folder / "velodyne" / "000001.bin")
    assert client.post("/api/v1/datasets", json={"path": "seq"}, headers=admin.headers).status_code == 201


def test_hardening_duplicate_registration_is_409_with_the_existing_id(client, factory):
    # defect 7: one folder registered 67 times
    admin = factory.user("admin")
    factory.sequence_folder("seq")
    first = client.post("/api/v1/datasets", json={"path": "seq", "ingest": False}, headers=admin.headers).json()
    seq_id = first["sequences"][0]["id"]
    r = client.post("/api/v1/datasets", json={"path": "seq", "ingest": False}, headers=admin.headers)
    assert r.status_code == 409 and r.json()["sequence_id"] == seq_id and str(seq_id) in r.json()["detail"]
    r = client.post("/api/v1/datasets", json={"path": "seq", "ingest": False, "reregister": True}, headers=admin.headers)
    assert r.status_code == 201 and r.json()["sequences"][0]["id"] != seq_id


def test_hardening_large_body_is_413_without_echo(client, factory):
    # defect 6: a 20 MB body got a 422 that echoed all of it
    op = factory.user("operator")
    big = b'{"version": "' + b"x" * (3 << 20) + b'"}'
    r = client.post("/api/v1/tracks/1/accept", content=big, headers={**op.headers, "content-type": "application/json"})
    assert r.status_code == 413 and len(r.content) < 200


def test_hardening_large_chunked_body_is_413(client, factory):
    op = factory.user("operator")

    def chunks():
        for _ in range(40):
            yield b"x" * (64 << 10)

    r = client.post("/api/v1/tracks/1/accept", content=chunks(), headers={**op.headers, "content-type": "application/json"})
    assert r.status_code == 413 and len(r.content) < 200


def test_hardening_operators_see_no_server_paths_of_sequences_or_models(client, factory, db):
    # defect 11: GET /sequences and /models showed operators absolute server paths
    from app.models import ModelVersion

    seq = factory.ingested_sequence(n_frames=3, n_objects=1)
    with db.write() as s:
        s.add(ModelVersion(name="m", kind="train", path="/srv/models/train_000001/best.pt"))
        s.commit()
    op, admin = factory.user("operator"), factory.user("admin")
    for url in ("/api/v1/sequences", f"/api/v1/sequences/{seq}", "/api/v1/models", "/api/v1/models/1"):
        body = client.get(url, headers=op.headers).text
        assert "/srv/" not in body and str(factory.settings.data_dir) not in body, url
    assert client.get("/api/v1/models/1", headers=admin.headers).json()["path"] == "/srv/models/train_000001/best.pt"
    assert client.get(f"/api/v1/sequences/{seq}", headers=admin.headers).json()["path"] is not None
