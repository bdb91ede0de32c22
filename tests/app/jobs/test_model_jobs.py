"""The `train` and `predict` jobs and the models API, on a sequence ingested through the fake
pipeline (4 x 8 x 8 samples) with a tiny network and a handful of steps."""

from __future__ import annotations

import re
import threading
import time
from pathlib import Path

from sqlalchemy import select

from app.crud.model_versions import load_training_set, register_model_version
from app.models import Job, ModelVersion, Track
from app.worker import Worker

CLASSES = ["car", "person", "car", "bush", "person", "bush"]
TRAIN = {"model_size": "tiny", "epochs": 2, "steps_per_epoch": 3, "batch_labelled": 4, "threads": 1}


def _act(client, caller, track_id, action, version, **body):
    r = client.post(f"/api/v1/tracks/{track_id}/{action}", json={"version": version, **body}, headers=caller.headers)
    assert r.status_code == 200, r.text


def _labelled_sequence(client, factory, n_label: int = 6) -> tuple[int, list[int]]:
    seq = factory.ingested_sequence(n_frames=8, n_objects=6)
    op = factory.user()
    ids = factory.track_ids(seq)
    for tid, cls in list(zip(ids, CLASSES, strict=True))[:n_label]:
        _act(client, op, tid, "label", 1, label=cls)
    return seq, ids


def _run(client, settings, db, admin, job_type, params) -> dict:
    r = client.post("/api/v1/jobs", json={"type": job_type, "params": params}, headers=admin.headers)
    assert r.status_code == 202, r.text
    assert Worker(settings, db=db).run_once()
    return client.get(f"/api/v1/jobs/{r.json()['id']}", headers=admin.headers).json()


def test_train_job_registers_model_listed_by_the_api(client, factory, settings, db):
    seq, _ = _labelled_sequence(client, factory)
    admin = factory.user("admin")
    job = _run(client, settings, db, admin, "train", {"sequence_ids": [seq], **TRAIN})
    assert job["status"] == "succeeded", job["error"]
    res = job["result"]
    assert res["metrics"]["epochs_run"] == 2 and res["metrics"]["data"]["pairs"] > 0
    assert len(job["result"]) >= 3 and job["progress"] == 1.0
    path = Path(res["path"])
    assert path.is_file() and settings.data_dir / "models" in path.parents

    models = client.get("/api/v1/models", headers=factory.user().headers).json()
    assert [m["id"] for m in models] == [res["model_id"]]
    m = models[0]
    assert m["kind"] == "train" and m["job_id"] == job["id"] and m["path"] is None  # no server paths for operators
    assert client.get("/api/v1/models", headers=admin.headers).json()[0]["path"] == str(path)
    assert m["val_mean_f"] is not None and set(m["val_f"]) >= {"car", "person", "bush"}
    detail = client.get(f"/api/v1/models/{m['id']}", headers=admin.headers).json()
    assert detail["config"]["params"]["constraints"] == "verified" and detail["config"]["samples"]["size"] == 8
    assert len(detail["metrics"]["train_loss"]) == 2 and detail["metrics"]["data"]["labelled_val"] > 0
    assert client.get("/api/v1/models/999", headers=admin.headers).status_code == 404
    assert client.get("/api/v1/models", params={"kind": "finetune"}, headers=admin.headers).json() == []
    for name in ("learning_curve.png", "confusion.png"):  # the PNGs written beside the checkpoint
        png = client.get(f"/api/v1/models/{m['id']}/plots/{name}", headers=admin.headers)
        assert png.status_code == 200 and png.headers["content-type"] == "image/png"
        assert png.content[:8] == b"\x89PNG\r\n\x1a\n" and len(png.content) > 2000
    assert client.get(f"/api/v1/models/{m['id']}/plots/other.png", headers=admin.headers).status_code == 422
    assert client.get("/api/v1/models/999/plots/confusion.png", headers=admin.headers).status_code == 404


def test_training_set_verified_vs_automatic_constraints(client, factory, settings, db):
    seq, ids = _labelled_sequence(client, factory, n_label=2)  # tracks 0 and 1 accepted
    from app.artifacts import ArtifactStore

    store = ArtifactStore(settings.artifacts_path)
    with db.read() as s:
        ver = load_training_set(s, store, [seq], "verified")
        auto = load_training_set(s, store, [seq], "automatic")
        none = load_training_set(s, store, [seq], "none")
        n_label_samples = s.scalar(select(Track.n_samples).where(Track.id == ids[0])) + s.scalar(
            select(Track.n_samples).where(Track.id == ids[1])
        )
    assert len(ver.data.labelled) == len(auto.data.labelled) == len(none.data.labelled) == n_label_samples
    assert len(none.data.pairs) == 0 and ver.pair_verified.all() and len(ver.data.pairs) == n_label_samples - 2
    assert len(auto.data.pairs) > len(ver.data.pairs) and not auto.pair_verified.all()
    assert (auto.data.pair_weights[auto.pair_verified] == 1.0).all()
    assert ver.data.samples.shape[1:] == (4, 8, 8)


def test_train_job_without_labels_fails_clearly(client, factory, settings, db):
    seq, _ = _labelled_sequence(client, factory, n_label=0)
    admin = factory.user("admin")
    job = _run(client, settings, db, admin, "train", {"sequence_ids": [seq], **TRAIN})
    assert job["status"] == "failed" and re.search(r"no (verified )?labels", job["error"])
    with db.read() as s:
        assert s.scalar(select(ModelVersion.id)) is None


def test_train_job_checks_sequences_and_role(client, factory):
    admin, op = factory.user("admin"), factory.user()
    r = client.post("/api/v1/jobs", json={"type": "train", "params": {"sequence_ids": [77]}}, headers=admin.headers)
    assert r.status_code == 404 and "77" in r.text
    r = client.post("/api/v1/jobs", json={"type": "train", "params": {"sequence_ids": [1]}}, headers=op.headers)
    assert r.status_code == 403
    r = client.post("/api/v1/jobs", json={"type": "train", "params": {"sequence_ids": []}}, headers=admin.headers)
    assert r.status_code == 422
    r = client.post("/api/v1/jobs", json={"type": "train", "params": {"sequence_ids": [1], "gamma": 2}},
                    headers=admin.headers)
    assert r.status_code == 422


def test_train_job_cancel_stops_without_registering(client, factory, settings, db):
    seq, _ = _labelled_sequence(client, factory)
    admin = factory.user("admin")
    params = {"sequence_ids": [seq], **TRAIN, "epochs": 1000, "steps_per_epoch": 5}
    job = client.post("/api/v1/jobs", json={"type": "train", "params": params}, headers=admin.headers).json()
    t = threading.Thread(target=Worker(settings, db=db).run_once)
    t.start()
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        now = client.get(f"/api/v1/jobs/{job['id']}", headers=admin.headers).json()
        if now["status"] == "running" and (now["result"] or {}).get("history"):
            break
        time.sleep(0.05)
    assert now["result"]["running"] is True and now["result"]["history"][0]["epoch"] == 0  # per-epoch metrics
    client.post(f"/api/v1/jobs/{job['id']}/cancel", headers=admin.headers)
    t.join(60)
    final = client.get(f"/api/v1/jobs/{job['id']}", headers=admin.headers).json()
    assert final["status"] == "cancelled" and final["progress"] < 1.0
    with db.read() as s:
        assert s.scalar(select(ModelVersion.id)) is None
    assert not (settings.data_dir / "models" / f"train_{job['id']:06d}").exists()


def test_predict_job_stores_track_classes_for_the_review_list(client, factory, settings, db):
    seq, ids = _labelled_sequence(client, factory)
    admin = factory.user("admin")
    trained = _run(client, settings, db, admin, "train", {"sequence_ids": [seq], **TRAIN})
    model_id = trained["result"]["model_id"]
    job = _run(client, settings, db, admin, "predict", {"model_id": model_id, "sequence_id": seq})
    assert job["status"] == "succeeded", job["error"]
    res = job["result"]
    assert res["tracks_predicted"] == len(ids) and res["verified_labels"]["samples"] > 0
    with db.read() as s:
        rows = s.execute(select(Track.id, Track.predicted_class, Track.predicted_confidence, Track.version)).all()
    assert all(c in CLASSES + ["cyclist", "trunk", "building", "unknown"] for _, c, _, _ in rows)
    assert all(1 / 7 <= p <= 1.0 for _, _, p, _ in rows) and all(v == 2 for *_, v in rows)  # version untouched
    cls = rows[0][1]
    listed = client.get("/api/v1/tracks", params={"sequence_id": seq, "predicted_class": cls}, headers=admin.headers)
    assert listed.json()["total"] == sum(c == cls for _, c, _, _ in rows)
    r = client.post("/api/v1/jobs", json={"type": "predict", "params": {"model_id": 99, "sequence_id": seq}},
                    headers=admin.headers)
    assert r.status_code == 404


def test_predict_job_sample_size_mismatch_fails_clearly(client, factory, settings, db, tmp_path):
    from pipeline.config import ModelConfig, SampleConfig
    from pipeline.model import get_model, save_checkpoint

    seq, _ = _labelled_sequence(client, factory, n_label=0)
    admin = factory.user("admin")
    samples, tiny = SampleConfig(size=16), ModelConfig(width=4, max_width=8, depth=2)
    ckpt = save_checkpoint(tmp_path / "m16.pt", get_model(tiny, samples), tiny, samples)
    with db.write() as s:
        mv = register_model_version(s, name="s16", kind="train", path=ckpt)
        s.commit()
        model_id = mv.id
    job = _run(client, settings, db, admin, "predict", {"model_id": model_id, "sequence_id": seq})
    assert job["status"] == "failed" and "re-ingest" in job["error"] and "16" in job["error"]
    with db.read() as s:
        assert s.scalar(select(Job.status).where(Job.id == job["id"])) == "failed"
        assert s.scalar(select(Track.predicted_class).limit(1)) is None


def test_train_job_split_by_track_leaves_validation_tracks_pairs_out():
    import numpy as np

    from app.crud.model_versions import TrainingSet
    from app.jobs.train import TrainParams, _JobData, _split
    from pipeline.config import SampleConfig
    from pipeline.label_sets import preset
    from pipeline.training import TrainingData

    # 8 tracks of 3 samples, each track's samples paired, two classes
    track = np.repeat(np.arange(1, 9), 3)
    pairs = np.array([[3 * t + a, 3 * t + b] for t in range(8) for a, b in ((0, 1), (1, 2))])
    data = TrainingData.build(np.zeros((24, 4, 8, 8), np.uint8), np.arange(24), np.repeat(np.arange(8) % 2, 3), pairs)
    job = _JobData(TrainingSet(data, np.arange(24), track, np.ones(len(pairs), bool)), preset("paper"), SampleConfig(),
                   None, None)
    train_data, val, train_sel, pair_sel = _split(job, TrainParams(sequence_ids=[1], val_fraction=0.5))
    val_tracks = np.setdiff1d(track, track[train_sel])
    assert len(val) == 3 * len(val_tracks) > 0
    assert not np.isin(track[train_data.pairs], val_tracks).any()
    assert pair_sel.sum() == len(train_data.pairs) == 2 * (8 - len(val_tracks))
