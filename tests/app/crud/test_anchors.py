"""Anchor proposals, answers and fine-tuning through the service (issue 7), on the fake pipeline.

The fake frames' samples are (4, 8, 8); a tiny checkpoint of that size stands in for a trained model.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from sqlalchemy import func, select, update

from app.crud import model_versions
from app.models import AnchorEvent, AnchorProposal, AnnotationEvent, Job, Label, ModelVersion, Segment, Track
from app.worker import Worker
from tests.app.fakes import SAMPLE_SHAPE


@pytest.fixture
def model_id(db, tmp_path: Path) -> int:
    import torch

    from pipeline.config import ModelConfig, SampleConfig
    from pipeline.model import get_model, save_checkpoint

    torch.manual_seed(0)
    mc = ModelConfig(width=4, max_width=8, depth=2, dropout=0.0)
    sc = SampleConfig(size=SAMPLE_SHAPE[1], foreground_channel=SAMPLE_SHAPE[0] == 4)
    path = save_checkpoint(tmp_path / "pre" / "best.pt", get_model(mc, sc), mc, sc, {"note": "untrained"})
    with db.write() as s:
        mv = model_versions.register_model_version(s, name="pretrained", kind="train", path=path)
        s.commit()
        return mv.id


def _run_job(client, settings, db, caller, type_: str, **params) -> dict:
    from tests.app.factories import Factory

    factory = Factory(db, settings)
    if caller.role != "admin":  # operators queue jobs on sequences an admin assigned them to (app/jobs/policy.py)
        factory.assign(caller, params["sequence_id"])
    r = client.post("/api/v1/jobs", json={"type": type_, "params": params}, headers=caller.headers)
    assert r.status_code == 202, r.text
    job_id = r.json()["id"]
    assert Worker(settings, db=db).run_once()
    with db.read() as s:
        job = s.get(Job, job_id)
        assert job is not None and job.status == "succeeded", (job.status, job.error)
        return dict(job.result or {})


def _anchors(client, caller, **params) -> list[dict]:
    r = client.get("/api/v1/anchors", params=params, headers=caller.headers)
    assert r.status_code == 200, r.text
    return r.json()["items"]


@pytest.mark.parametrize("strategy", ["confident", "entropy", "diverse"])
def test_propose_sample_level_stores_requested_count(client, factory, settings, db, model_id, strategy):
    seq = factory.ingested_sequence(n_frames=6, n_objects=4)  # 21 samples on 4 tracks
    op = factory.user()
    res = _run_job(client, settings, db, op, "propose_anchors", sequence_id=seq, model_id=model_id,
                   strategy=strategy, per_class=2, unknown=3)
    assert res["proposals"] == 2 * 6 + 3 and res["samples_scored"] == 21 and res["model_id"] == model_id
    items = _anchors(client, op, sequence_id=seq)
    assert len(items) == 15
    assert len({a["segment_id"] for a in items}) == 15  # no sample twice
    assert {a["level"] for a in items} == {"sample"} and {a["strategy"] for a in items} == {strategy}
    assert sorted(sum(a["proposed_class"] == c for a in items) for c in ("person", "unknown")) == [2, 3]
    assert all(a["sample_url"] == f"/api/v1/segments/{a['segment_id']}/sample.png" for a in items)
    assert {a["model_id"] for a in items} == {model_id}


def test_confirmed_track_anchor_labels_whole_track(client, factory, settings, db, model_id):
    seq = factory.ingested_sequence(n_frames=6, n_objects=4)
    op = factory.user()
    res = _run_job(client, settings, db, op, "propose_anchors", sequence_id=seq, model_id=model_id,
                   strategy="track", per_class=1, unknown=1, min_track_samples=1)
    assert res["proposals"] == 4  # only 4 tracks exist
    items = _anchors(client, op, sequence_id=seq, status="proposed")
    assert len({a["track_id"] for a in items}) == 4 and {a["level"] for a in items} == {"track"}
    a = items[0]
    r = client.post(f"/api/v1/anchors/{a['id']}/confirm", headers=op.headers)
    assert r.status_code == 200, r.text
    body = r.json()
    assert body["status"] == "confirmed" and body["answer_class"] == a["proposed_class"] and not body["corrected"]
    assert body["decided_by"] == op.name
    track = client.get(f"/api/v1/tracks/{a['track_id']}", headers=op.headers).json()
    assert track["status"] == "accepted" and track["label"] == a["proposed_class"]
    with db.read() as s:
        n_valid = s.scalar(select(func.count()).select_from(Segment).where(
            Segment.track_id == a["track_id"], Segment.valid.is_(True)))
        labels = s.execute(select(Label.class_name, Label.user_id).where(Label.track_id == a["track_id"])).all()
        assert n_valid >= 4 and len(labels) == n_valid  # every sample of the track
        assert {(c, u) for c, u in labels} == {(a["proposed_class"], op.id)}
        ev = s.scalars(select(AnnotationEvent).where(AnnotationEvent.track_id == a["track_id"])).all()
        assert [(e.action, e.user_id) for e in ev] == [("label", op.id)]  # the track's own event log
    events = client.get(f"/api/v1/anchors/{a['id']}/events", headers=op.headers).json()
    assert [(e["action"], e["user_id"], e["class_name"]) for e in events] == [("confirm", op.id, a["proposed_class"])]


def test_correct_reject_and_summary(client, factory, settings, db, model_id):
    seq = factory.ingested_sequence(n_frames=6, n_objects=4)
    op = factory.user()
    _run_job(client, settings, db, op, "propose_anchors", sequence_id=seq, model_id=model_id,
             strategy="confident", per_class=1, unknown=1)
    a, b = _anchors(client, op, sequence_id=seq)[:2]
    other = "bush" if a["proposed_class"] != "bush" else "car"
    assert client.post(f"/api/v1/anchors/{a['id']}/correct", json={"label": "lorry"}, headers=op.headers).status_code == 422
    r = client.post(f"/api/v1/anchors/{a['id']}/correct", json={"label": other}, headers=op.headers)
    assert r.status_code == 200 and r.json()["answer_class"] == other and r.json()["corrected"]
    assert client.post(f"/api/v1/anchors/{b['id']}/reject", headers=op.headers).json()["status"] == "rejected"
    summary = client.get("/api/v1/anchors/summary", params={"sequence_id": seq}, headers=op.headers).json()
    assert summary["by_status"] == {"confirmed": 1, "rejected": 1, "proposed": 5}
    assert summary["per_class"][other]["confirmed"] == 1
    assert summary["per_class"][a["proposed_class"]]["corrected"] == 1
    # sample-level answers label no track
    assert client.get(f"/api/v1/tracks/{a['track_id']}", headers=op.headers).json()["label"] is None
    assert [x["id"] for x in _anchors(client, op, sequence_id=seq, status="rejected")] == [b["id"]]


def test_answers_to_gone_or_decided_proposals_are_404_or_409(client, factory, settings, db, model_id):
    seq = factory.ingested_sequence(n_frames=6, n_objects=4)
    op, op2 = factory.user(), factory.user()
    _run_job(client, settings, db, op, "propose_anchors", sequence_id=seq, model_id=model_id,
             strategy="track", per_class=1, unknown=1, min_track_samples=1)
    first = _anchors(client, op, sequence_id=seq)
    a, b, c = first[:3]
    assert client.post(f"/api/v1/anchors/{a['id']}/confirm", headers=op.headers).status_code == 200
    # already decided: 409 for every answer, by anyone, and nothing changes
    for path, kw in (("confirm", {}), ("reject", {}), ("correct", {"json": {"label": "car"}})):
        r = client.post(f"/api/v1/anchors/{a['id']}/{path}", headers=op2.headers, **kw)
        assert r.status_code == 409 and op.name in r.json()["detail"], r.text
    # the track was discarded after it was proposed: 409, the proposal stays open
    t = client.get(f"/api/v1/tracks/{b['track_id']}", headers=op.headers).json()
    client.post(f"/api/v1/tracks/{b['track_id']}/discard", json={"version": t["version"]}, headers=op.headers)
    assert client.post(f"/api/v1/anchors/{b['id']}/confirm", headers=op.headers).status_code == 409
    assert client.get(f"/api/v1/anchors/{b['id']}", headers=op.headers).json()["status"] == "proposed"
    # a new proposal run replaces the open proposals: answering an old one is 404
    _run_job(client, settings, db, op, "propose_anchors", sequence_id=seq, model_id=model_id,
             strategy="track", per_class=1, unknown=1, min_track_samples=1)
    for path, kw in (("confirm", {}), ("reject", {}), ("correct", {"json": {"label": "car"}})):
        assert client.post(f"/api/v1/anchors/{c['id']}/{path}", headers=op.headers, **kw).status_code == 404
    assert client.get(f"/api/v1/anchors/{c['id']}", headers=op.headers).status_code == 404
    assert client.get(f"/api/v1/anchors/{c['id']}/events", headers=op.headers).status_code == 404
    second = _anchors(client, op, sequence_id=seq)
    assert a["id"] in {x["id"] for x in second}  # answered proposals are kept
    new_tracks = {x["track_id"] for x in second if x["status"] == "proposed"}
    assert a["track_id"] not in new_tracks and b["track_id"] not in new_tracks  # labelled / discarded left out
    # the sequence re-ingested: every proposal is gone
    factory.queue_ingest(seq, force=True)
    from tests.app.fakes import fake_pipeline

    with fake_pipeline(n_frames=6, n_objects=4):
        assert Worker(settings, db=db).run_once()
    assert client.post(f"/api/v1/anchors/{a['id']}/reject", headers=op.headers).status_code == 404
    assert client.post("/api/v1/anchors/2147483647/confirm", headers=op.headers).status_code == 404
    assert client.post("/api/v1/anchors/0/confirm", headers=op.headers).status_code == 422


def test_track_anchor_on_sequence_not_ready_is_409(client, factory, settings, db, model_id):
    from app.models import Sequence

    seq = factory.ingested_sequence(n_frames=6, n_objects=2)
    op = factory.user()
    _run_job(client, settings, db, op, "propose_anchors", sequence_id=seq, model_id=model_id,
             strategy="track", per_class=1, unknown=1, min_track_samples=1)
    a = _anchors(client, op, sequence_id=seq)[0]
    with db.write() as s:
        s.execute(update(Sequence).where(Sequence.id == seq).values(status="ingesting"))
        s.commit()
    assert client.post(f"/api/v1/anchors/{a['id']}/confirm", headers=op.headers).status_code == 409
    with db.read() as s:  # nothing half-written
        p = s.get(AnchorProposal, a["id"])
        assert p is not None and p.status == "proposed"
        assert s.scalar(select(func.count()).select_from(AnchorEvent)) == 0


def test_propose_and_finetune_jobs_check_their_inputs(client, factory, model_id):
    seq = factory.ingested_sequence(n_frames=3, n_objects=2)
    op = factory.user()
    for type_, params, code in (
        ("propose_anchors", {"sequence_id": 999, "model_id": model_id}, 404),
        ("propose_anchors", {"sequence_id": seq, "model_id": 999}, 404),
        ("propose_anchors", {"sequence_id": seq, "strategy": "random"}, 422),
        ("finetune", {"sequence_id": seq, "model_id": 999}, 404),
        ("finetune", {"sequence_id": seq, "model_id": model_id, "constraints": "all"}, 422),
    ):
        r = client.post("/api/v1/jobs", json={"type": type_, "params": params}, headers=op.headers)
        assert r.status_code == code, (type_, params, r.text)


def test_finetune_job_registers_child_model(client, factory, settings, db, model_id):
    seq = factory.ingested_sequence(n_frames=6, n_objects=4)
    op = factory.user()
    _run_job(client, settings, db, op, "propose_anchors", sequence_id=seq, model_id=model_id,
             strategy="confident", per_class=1, unknown=1)
    items = _anchors(client, op, sequence_id=seq)
    for a in items[:3]:
        client.post(f"/api/v1/anchors/{a['id']}/confirm", headers=op.headers)
    # one track labelled through the review actions, too; its pairs become verified constraints
    tid = items[3]["track_id"]
    t = client.get(f"/api/v1/tracks/{tid}", headers=op.headers).json()
    client.post(f"/api/v1/tracks/{tid}/label", json={"version": t["version"], "label": "car"}, headers=op.headers)
    admin = factory.user("admin")  # the chained predict rewrites every track's prediction: admins only
    res = _run_job(client, settings, db, admin, "finetune", sequence_id=seq, model_id=model_id,
                   epochs=2, steps_per_epoch=2, threads=1, predict=True)
    # the chained predict job re-labels the sequence's tracks with the new model
    assert res["predict_job_id"] and res["predict_error"] is None
    assert Worker(settings, db=db).run_once()
    with db.read() as s:
        job = s.get(Job, res["predict_job_id"])
        assert job is not None and job.status == "succeeded", job.error
        assert job.params["model_id"] == res["model_id"] and job.created_by_id == admin.id
        assert s.scalar(select(func.count()).select_from(Track).where(Track.predicted_class.is_(None))) == 0
    with db.read() as s:
        mv = s.get(ModelVersion, res["model_id"])
        assert mv is not None and mv.kind == "finetune" and mv.parent_id == model_id and mv.created_by_id == admin.id
        assert Path(mv.path).is_file()
        n_track = s.scalar(select(func.count()).select_from(Label).where(Label.track_id == tid))
        pairs = s.scalar(select(Track.n_samples).where(Track.id == tid)) - 1
    anchored = {a["segment_id"] for a in items[:3]}
    with db.read() as s:
        on_track = s.scalars(select(Segment.id).where(Segment.track_id == tid)).all()
    expected = n_track + len(anchored - set(on_track))
    assert res["labelled"] == expected and res["pairs"] == pairs
    assert sum(res["anchors_per_class"].values()) == expected
    from pipeline.model import load_checkpoint

    model, meta = load_checkpoint(mv.path)
    assert meta.metrics["parent"] and meta.metrics["kind"] == "finetune"
    assert np.isfinite(meta.metrics["train_loss"]).all()


def test_finetune_job_defaults_follow_the_library():
    """The REST job trains with the library's fine-tuning defaults (chosen by the experiment)."""
    from app.jobs.finetune import FinetuneParams, finetune_job_config
    from pipeline.config import TrainingConfig

    params = FinetuneParams(sequence_id=1, model_id=1)
    assert finetune_job_config(params) == TrainingConfig().finetuning().model_copy(update={"weighted_pairs": True})
    assert finetune_job_config(FinetuneParams(sequence_id=1, model_id=1, epochs=3)).epochs == 3


def test_propose_without_a_registered_model_uses_the_shipped_default(client, factory, settings, db, tmp_path,
                                                                     monkeypatch):
    import torch

    import pipeline.model
    from pipeline.config import ModelConfig, SampleConfig
    from pipeline.model import get_model, save_checkpoint

    torch.manual_seed(0)
    mc = ModelConfig(width=4, max_width=8, depth=2, dropout=0.0)
    sc = SampleConfig(size=SAMPLE_SHAPE[1], foreground_channel=SAMPLE_SHAPE[0] == 4)
    # the shipped model reads 64 x 64 samples; the fake pipeline's are 8 x 8
    monkeypatch.setattr(pipeline.model, "DEFAULT_MODEL", save_checkpoint(tmp_path / "d.pt", get_model(mc, sc), mc, sc))
    seq = factory.ingested_sequence(n_frames=6, n_objects=4)
    op = factory.user()
    res = _run_job(client, settings, db, op, "propose_anchors", sequence_id=seq, strategy="confident", per_class=1,
                   unknown=1)
    assert res["model_id"] is None and res["proposals"] == 7
    assert {a["model_id"] for a in _anchors(client, op, sequence_id=seq)} == {None}
    monkeypatch.setattr(pipeline.model, "DEFAULT_MODEL", tmp_path / "missing.pt")
    r = client.post("/api/v1/jobs", json={"type": "propose_anchors", "params": {"sequence_id": seq}}, headers=op.headers)
    assert r.status_code == 404 and "no model is registered" in r.text
