from __future__ import annotations

import os

from app.models import Job


def test_datasets_register_queues_ingest(client, factory):
    admin = factory.user("admin")
    factory.sequence_folder("seq")
    r = client.post("/api/v1/datasets", json={"path": "seq"}, headers=admin.headers)
    assert r.status_code == 201, r.text
    seq = r.json()["sequences"][0]
    assert seq["format"] == "kitti" and seq["status"] == "registered" and seq["ingest_job_id"] is not None
    job = client.get(f"/api/v1/jobs/{seq['ingest_job_id']}", headers=admin.headers).json()
    assert (job["type"], job["status"], job["params"]["sequence_id"]) == ("ingest", "queued", seq["id"])


def test_datasets_register_absolute_path_under_root(client, factory):
    admin = factory.user("admin")
    folder = factory.sequence_folder("abs")
    r = client.post("/api/v1/datasets", json={"path": str(folder), "ingest": False}, headers=admin.headers)
    assert r.status_code == 201 and r.json()["sequences"][0]["ingest_job_id"] is None


def test_datasets_dotdot_is_403(client, factory):
    admin = factory.user("admin")
    factory.sequence_folder("seq")
    r = client.post("/api/v1/datasets", json={"path": "seq/../seq"}, headers=admin.headers)
    assert r.status_code == 403


def test_datasets_outside_roots_is_403(client, factory, tmp_path):
    admin = factory.user("admin")
    outside = tmp_path / "elsewhere"
    (outside / "velodyne").mkdir(parents=True)
    r = client.post("/api/v1/datasets", json={"path": str(outside)}, headers=admin.headers)
    assert r.status_code == 403


def test_datasets_symlink_out_of_roots_is_403(client, factory, tmp_path, settings):
    admin = factory.user("admin")
    outside = tmp_path / "elsewhere"
    (outside / "velodyne").mkdir(parents=True)
    os.symlink(outside, settings.data_roots[0] / "link")
    r = client.post("/api/v1/datasets", json={"path": "link"}, headers=admin.headers)
    assert r.status_code == 403


def test_datasets_missing_path_is_404(client, factory):
    admin = factory.user("admin")
    assert client.post("/api/v1/datasets", json={"path": "nope"}, headers=admin.headers).status_code == 404


def test_datasets_bad_config_is_422(client, factory):
    admin = factory.user("admin")
    factory.sequence_folder("seq")
    body = {"path": "seq", "config": {"samples": {"size": "big"}}}
    assert client.post("/api/v1/datasets", json=body, headers=admin.headers).status_code == 422


def test_datasets_inspect_counts_ingested_rows(client, factory):
    from tests.app.fakes import expected_counts

    seq = factory.ingested_sequence(n_frames=5, n_objects=4)
    admin = factory.user("admin")
    ds = client.get("/api/v1/datasets", headers=admin.headers).json()[0]
    detail = client.get(f"/api/v1/datasets/{ds['id']}", headers=admin.headers).json()
    stats = detail["stats"][0]
    exp = expected_counts(5, 4)
    assert stats["sequence"]["id"] == seq
    assert (stats["frames"], stats["segments"], stats["tracks"], stats["constraints"]) == (
        exp["frames"], exp["segments"], exp["tracks"], exp["constraints"]
    )


def test_datasets_second_ingest_while_queued_is_409(client, factory, db):
    admin = factory.user("admin")
    factory.sequence_folder("seq")
    seq = client.post("/api/v1/datasets", json={"path": "seq"}, headers=admin.headers).json()["sequences"][0]
    r = client.post(f"/api/v1/sequences/{seq['id']}/ingest", json={}, headers=admin.headers)
    assert r.status_code == 409
    with db.read() as s:
        assert s.query(Job).count() == 1


def test_datasets_operator_gets_403_but_lists_sequences(client, factory):
    seq = factory.ingested_sequence(n_frames=2, n_objects=1)
    op = factory.user()
    assert client.get("/api/v1/datasets", headers=op.headers).status_code == 403
    assert client.get("/api/v1/datasets/1", headers=op.headers).status_code == 403
    listed = client.get("/api/v1/sequences", params={"status": "ready"}, headers=op.headers).json()
    assert [s["id"] for s in listed] == [seq]
