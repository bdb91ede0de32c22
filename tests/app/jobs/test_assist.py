"""The model in the review loop: the worker queues `assist` runs as reviews come in (debounced),
each classifies every track from the reviews so far and orders the review queue."""

from __future__ import annotations

import pytest
from sqlalchemy import select

from app import crud
from app.crud.model_versions import register_model_version
from app.models import Job, Track
from app.worker import Worker

CLASSES = ["car", "bush", "car", "bush", "car", "bush"]


@pytest.fixture
def tiny_model(tmp_path):
    """A small CNN that reads the fake pipeline's 4 x 8 x 8 samples."""
    from pipeline.config import ModelConfig, SampleConfig
    from pipeline.model import get_model, save_checkpoint

    samples, net = SampleConfig(size=8), ModelConfig(width=4, max_width=8, depth=2)
    return save_checkpoint(tmp_path / "m8.pt", get_model(net, samples), net, samples)


def _sequence_with_model(factory, db, tiny_model, n_objects: int = 6, label_set: str = "paper") -> int:
    """A fake sequence and a model registered as trained on it (so assist runs take it as base)."""
    seq = factory.ingested_sequence(n_frames=6, n_objects=n_objects, label_set=label_set)
    with db.write() as s:
        register_model_version(s, name="m8", kind="train", path=tiny_model, config={"params": {"sequence_ids": [seq]}})
        s.commit()
    return seq


def _label(client, caller, factory, ids, classes):
    for tid, cls in zip(ids, classes, strict=True):
        r = client.post(f"/api/v1/tracks/{tid}/label", json={"version": factory.track(tid).version, "label": cls},
                        headers=caller.headers)
        assert r.status_code == 200, r.text


def _assist_jobs(db) -> list[Job]:
    with db.read() as s:
        return list(s.scalars(select(Job).where(Job.type == "assist").order_by(Job.id)).all())


def test_assist_predicts_every_track_and_orders_the_queue(client, factory, db, settings, tiny_model):
    seq = _sequence_with_model(factory, db, tiny_model)
    ids = factory.track_ids(seq)
    op = factory.user()
    _label(client, op, factory, ids[:5], CLASSES[:5])
    worker = Worker(settings, db=db)
    assert len(worker.schedule()) == 1
    assert worker.run_once()
    job = _assist_jobs(db)[-1]
    assert job.status == "succeeded", job.error
    assert job.result["reviewed_classes"] == ["bush", "car"] and job.result["tracks_predicted"] == len(ids)
    assert len(job.result["held_out"]["truth"]) == 5
    with db.read() as s:
        rows = s.execute(select(Track.id, Track.predicted_class, Track.predicted_confidence, Track.priority, Track.n_points)
                         .where(Track.sequence_id == seq)).all()
    assert all(c is not None for _, c, *_ in rows)
    for _, _, conf, priority, n in rows:
        assert priority == pytest.approx(crud.queue_priority(n, conf))
    pending = [r for r in rows if r.id not in ids[:5]]
    top = max(pending, key=lambda r: (r.priority, -r.id))
    assert client.post("/api/v1/review/next", headers=op.headers).json()["id"] == top.id


def test_assist_learns_the_classes_of_a_sequence_of_another_label_set(client, factory, db, settings, tiny_model):
    """The base CNN knows the paper classes; the sequence is nuScenes': the head predicts nothing
    from one reviewed class, then the sequence's own classes once two are reviewed."""
    settings.assist_every = 1
    seq = _sequence_with_model(factory, db, tiny_model, label_set="nuscenes")
    ids = factory.track_ids(seq)
    op = factory.user()
    worker = Worker(settings, db=db)
    classes = ["car", "vegetation"] * 3
    _label(client, op, factory, ids[:1], classes[:1])
    assert len(worker.schedule()) == 1 and worker.run_once()
    job = _assist_jobs(db)[-1]
    assert job.status == "succeeded", job.error
    assert job.result["tracks_predicted"] == 0
    _label(client, op, factory, ids[1:5], classes[1:5])
    assert len(worker.schedule()) == 1 and worker.run_once()
    job = _assist_jobs(db)[-1]
    assert job.status == "succeeded", job.error
    assert job.result["tracks_predicted"] == len(ids) and job.result["reviewed_classes"] == ["car", "vegetation"]
    with db.read() as s:
        predicted = set(s.scalars(select(Track.predicted_class).where(Track.sequence_id == seq)).all())
    assert predicted and predicted <= {"car", "vegetation", "no_object"}


def test_assist_runs_once_per_batch_of_reviews(client, factory, db, settings, tiny_model):
    settings.assist_every = 3
    seq = _sequence_with_model(factory, db, tiny_model)
    ids = factory.track_ids(seq)
    op = factory.user()
    worker = Worker(settings, db=db)
    assert len(worker.schedule()) == 1  # the first run when the sequence is ready
    assert worker.schedule() == []  # one queued already: reviews wait for the next run
    assert worker.run_once()
    _label(client, op, factory, ids[:2], CLASSES[:2])
    assert worker.schedule() == []  # 2 reviews < 3
    _label(client, op, factory, ids[2:3], CLASSES[2:3])
    new = worker.schedule()
    assert len(new) == 1
    with db.read() as s:
        job = s.get(Job, new[0])
        assert job.params["after_event"] == max(e.id for t in ids[:3] for e in crud.track_events(s, t))
    _label(client, op, factory, ids[3:6], CLASSES[3:6])  # arrive while the run waits
    assert worker.schedule() == []
    assert worker.run_once()
    assert len(worker.schedule()) == 1  # the reviews that came meanwhile start the next run


def test_assist_is_off_with_assist_every_zero(factory, db, settings, tiny_model):
    settings.assist_every = 0
    _sequence_with_model(factory, db, tiny_model)
    assert Worker(settings, db=db).schedule() == []


def test_assist_predictions_feed_bulk_accept(client, factory, db, settings, tiny_model):
    seq = _sequence_with_model(factory, db, tiny_model)
    ids = factory.track_ids(seq)
    op = factory.user()
    _label(client, op, factory, ids[:4], CLASSES[:4])
    worker = Worker(settings, db=db)
    worker.schedule()
    worker.run_once()
    with db.read() as s:
        cls, conf = s.execute(select(Track.predicted_class, Track.predicted_confidence).where(Track.id == ids[4])).one()
    r = client.post(f"/api/v1/sequences/{seq}/bulk-accept", json={"class_name": cls, "min_confidence": conf},
                    headers=op.headers)
    assert r.status_code == 200, r.text
    assert factory.track(ids[4]).label_source == "bulk"


def test_a_region_reruns_assist_and_puts_the_tracks_it_labels_last_in_the_queue(client, factory, db, settings,
                                                                                tiny_model):
    """A review cannot change the points a region with heights labels, so the run after a region
    was drawn counts only a track's other points in its priority; drawing or undoing one is due
    at once, whatever the reviews."""
    settings.assist_every = 100
    seq = _sequence_with_model(factory, db, tiny_model)
    ids = factory.track_ids(seq)
    op = factory.user()
    _label(client, op, factory, ids[:4], CLASSES[:4])
    worker = Worker(settings, db=db)
    assert len(worker.schedule()) == 1 and worker.run_once()
    assert worker.schedule() == []  # the first run took the reviews in; no region yet
    everywhere = [[-1e5, -1e5], [1e5, -1e5], [1e5, 1e5], [-1e5, 1e5]]
    r = client.post(f"/api/v1/sequences/{seq}/ground-regions", headers=op.headers,
                    json={"class_name": "bush", "polygon": everywhere, "z_min": -1e4, "z_max": 1e4})
    assert r.status_code == 200, r.text
    assert len(worker.schedule()) == 1 and worker.run_once()
    job = _assist_jobs(db)[-1]
    assert job.status == "succeeded", job.error
    assert job.result["regions"] == 1
    with db.read() as s:
        priorities = s.scalars(select(Track.priority).where(Track.sequence_id == seq, Track.status == "pending")).all()
    assert priorities and all(p == 0 for p in priorities)  # every point of every track lies in the prism
    assert worker.schedule() == []
    assert client.delete(f"/api/v1/ground-regions/{r.json()['id']}", headers=op.headers).status_code == 200
    assert len(worker.schedule()) == 1 and worker.run_once()  # undone: due again, and the priorities come back
    with db.read() as s:
        rows = s.execute(select(Track.priority, Track.n_points, Track.predicted_confidence)
                         .where(Track.sequence_id == seq, Track.status == "pending")).all()
    assert all(p == pytest.approx(crud.queue_priority(n, c)) for p, n, c in rows) and any(p > 0 for p, _, _ in rows)


def test_the_head_learns_the_class_of_the_tracks_a_prism_labels(client, factory, db, settings, tiny_model):
    """A prism drawn over tracks nobody reviewed teaches the head its class, as reviews of them
    would: no review said "cyclist", yet the tracks inside the prism are predicted so, and the
    bulk preview's held-out tracks are still the reviewed ones alone."""
    settings.assist_every = 100
    seq = _sequence_with_model(factory, db, tiny_model)
    ids = factory.track_ids(seq)
    op = factory.user()
    _label(client, op, factory, ids[:5], CLASSES[:5])
    everywhere = [[-1e5, -1e5], [1e5, -1e5], [1e5, 1e5], [-1e5, 1e5]]
    r = client.post(f"/api/v1/sequences/{seq}/ground-regions", headers=op.headers,
                    json={"class_name": "cyclist", "polygon": everywhere, "z_min": -1e4, "z_max": 1e4})
    assert r.status_code == 200, r.text
    worker = Worker(settings, db=db)
    assert len(worker.schedule()) == 1 and worker.run_once()
    job = _assist_jobs(db)[-1]
    assert job.status == "succeeded", job.error
    assert job.result["region_samples"] > 0 and job.result["reviewed_classes"] == ["bush", "car"]
    assert len(job.result["held_out"]["truth"]) == 5
    with db.read() as s:
        pending = s.scalars(select(Track.predicted_class).where(Track.sequence_id == seq,
                                                                Track.status == "pending")).all()
    assert pending and all(c == "cyclist" for c in pending)
