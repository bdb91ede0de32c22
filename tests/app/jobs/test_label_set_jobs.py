"""Predict and fine-tune jobs refuse, when queued, a model trained on another label set (422)."""

from __future__ import annotations

import pytest

from app.crud.model_versions import register_model_version
from app.models import Job


def _register(db, tmp_path, label_set: str) -> int:
    from pipeline.config import ModelConfig, SampleConfig
    from pipeline.label_sets import preset
    from pipeline.model import get_model, save_checkpoint

    classes = preset(label_set).sample_class_names
    tiny, samples = ModelConfig(width=4, max_width=8, depth=2, num_classes=len(classes)), SampleConfig(size=8)
    path = save_checkpoint(tmp_path / f"{label_set}.pt", get_model(tiny, samples), tiny, samples, classes=classes,
                           label_set=label_set)
    with db.write() as s:
        mv = register_model_version(s, name=label_set, kind="train", path=path)
        s.commit()
        return mv.id


@pytest.mark.parametrize("job_type", ["predict", "finetune"])
def test_label_set_jobs_model_of_another_label_set_is_422(client, factory, db, tmp_path, job_type):
    seq = factory.ingested_sequence(n_frames=4, n_objects=2)
    admin = factory.user("admin")
    model_id = _register(db, tmp_path, "semantickitti")
    r = client.post("/api/v1/jobs", json={"type": job_type, "params": {"model_id": model_id, "sequence_id": seq}},
                    headers=admin.headers)
    assert r.status_code == 422, r.text
    assert f"model {model_id}" in r.text and "'semantickitti'" in r.text and "not on 'paper'" in r.text
    with db.read() as s:
        assert s.query(Job).filter(Job.type == job_type).count() == 0


def test_label_set_jobs_model_of_the_sequence_label_set_is_queued(client, factory, db, tmp_path):
    seq = factory.ingested_sequence(n_frames=4, n_objects=2)
    admin = factory.user("admin")
    model_id = _register(db, tmp_path, "paper")
    r = client.post("/api/v1/jobs", json={"type": "predict", "params": {"model_id": model_id, "sequence_id": seq}},
                    headers=admin.headers)
    assert r.status_code == 202, r.text


def test_label_set_jobs_the_default_model_is_refused_for_anchors_on_a_sequence_of_another_set(client, factory, db):
    """Anchors are the CNN's own proposals, so its classes must be the sequence's (the assist head
    instead learns the sequence's classes over any CNN: tests/app/jobs/test_assist.py)."""
    seq = factory.ingested_sequence(n_frames=4, n_objects=2, label_set="nuscenes")
    admin = factory.user("admin")
    r = client.post("/api/v1/jobs", json={"type": "propose_anchors", "params": {"sequence_id": seq}},
                    headers=admin.headers)
    assert r.status_code == 422, r.text
    assert "trained on label set 'paper'" in r.text and "not on 'nuscenes'" in r.text
