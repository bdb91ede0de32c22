"""The operator benchmark's simulated operator, over the real service (in-process) and the fake
pipeline: its action count is the event log's, and it reads the truth of what it is shown only."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from fastapi.testclient import TestClient

from app.crud.model_versions import register_model_version
from app.main import create_app
from app.worker import Worker
from bench.effort.operator import Operator, Policy
from bench.effort.service import Api
from bench.effort.truth import TruthStore
from pipeline.classes import GROUND


def _truth(api: Api, frames) -> dict[str, np.ndarray]:
    """Track key o + 1 (object o) is class o % 3 (person, car, cyclist); other points are ground."""
    out = {}
    for f in frames:
        p = api.payload(f.id)
        seg_keys = {}
        for tid in np.unique(p["track"][p["track"] > 0]):
            seg_keys[int(tid)] = api.get(f"/tracks/{int(tid)}")["key"]
        cls = np.full(len(p["track"]), GROUND, np.uint8)
        for tid, key in seg_keys.items():
            cls[p["track"] == tid] = (key - 1) % 3
        out[f.name] = cls
    return out


@pytest.fixture
def setup(settings, db, factory, tmp_path):
    from pipeline.config import ModelConfig, SampleConfig
    from pipeline.model import get_model, save_checkpoint

    seq = factory.ingested_sequence(n_frames=5, n_objects=8)
    net, samples = ModelConfig(width=4, max_width=8, depth=2), SampleConfig(size=8)
    torch.manual_seed(0)  # one model, so the predictions a bulk takes are the same every run
    ckpt = save_checkpoint(tmp_path / "m8.pt", get_model(net, samples), net, samples)
    with db.write() as s:
        register_model_version(s, name="m8", kind="train", path=ckpt, config={"params": {"sequence_ids": [seq]}})
        s.commit()
    client = TestClient(create_app(settings, db=db), base_url="http://testserver/api/v1")
    apis = [Api(client, factory.user(role).token) for role in ("admin", "operator", "reviewer")]
    frames = apis[1].frames(seq)
    store = TruthStore(_truth(apis[0], frames))
    policy = Policy(bulk_every=6, bulk_confidence=0.0, bulk_precision=0.0, bulk_support=0, audit_per_bulk=2,
                    wait_for_model=False)
    op = Operator(apis[1], apis[2], apis[0], seq, frames, store, policy)
    yield seq, op, Worker(settings, db=db)
    client.close()


def _settle(worker: Worker) -> None:
    """Run every job the worker has due (the model in the loop after the newest reviews)."""
    worker.schedule()
    while worker.run_once():
        pass


def _work(op: Operator, worker: Worker, reviews: int) -> None:
    for _ in range(reviews):
        _settle(worker)
        if not op.review_next():
            break
        if op.counts.reviews % op.policy.bulk_every == 0:
            op.bulk_round()


def _review_six(seq: int, op: Operator, worker: Worker) -> None:
    """Three reviews of the smallest tracks, then three of the queue's. The queue offers the
    largest tracks first, and a bulk takes only tracks at least as large as the smallest reviewed
    one the model was checked on: opening the smallest from the track list first leaves pending
    tracks above that size."""
    tracks = sorted(op.admin.get("/tracks", params={"sequence_id": seq, "limit": 100})["items"], key=lambda t: t["n_points"])
    for t in tracks[:3]:
        op.review(op.op.get(f"/tracks/{t['id']}"))
        _settle(worker)
    for _ in range(3):
        op.review_next()
        _settle(worker)


def test_effort_action_count_is_the_event_log_s(setup, db):
    from app import crud

    seq, op, worker = setup
    _review_six(seq, op, worker)
    op.bulk_round()  # on the model of all six reviews
    op.review_next()
    c = op.counts
    assert c.reviews >= 6 and c.bulk_accepts >= 1 and c.audits >= 1
    with db.read() as s:
        assert crud.operation_count(s, seq) == c.edits + c.audit_corrections


def test_effort_operator_reads_the_truth_of_shown_tracks_only(setup):
    seq, op, worker = setup
    _work(op, worker, 7)
    assert op.store.reads
    payloads = {f.name: op.op.payload(f.id)["track"] for f in op.frames}
    for item, frame, points in op.store.reads:
        assert item is not None and set(payloads[frame][points].tolist()) == {item}
    op.store.forget()
    with pytest.raises(PermissionError):
        op.store.read(op.frames[0].name, np.array([0]))


def test_each_bulk_is_scored_against_the_truth_as_taken_before_its_audit(setup):
    from types import SimpleNamespace

    from bench.effort.score import as_accepted_summary, bulk_as_accepted, bulk_tracks

    seq, op, worker = setup
    truth = SimpleNamespace(all=op.store.truth, label_set=op.label_set)
    _review_six(seq, op, worker)
    records, before = [], set(bulk_tracks(op.admin, seq))

    def score(bulk):
        nonlocal before
        now = bulk_tracks(op.admin, seq)
        records.append(bulk_as_accepted(op.admin, bulk, [t for i, t in now.items() if i not in before], op.frames, truth))
        before = set(now)

    op.on_bulk = score
    op.bulk_round()
    assert records and all(r["tracks"] == r["n_tracks"] for r in records)
    names = op.label_set.point_class_names
    for r in records:  # the track's key decides its class in this truth (`_truth`)
        truths = {i: names[(op.admin.get(f"/tracks/{i}")["key"] - 1) % 3] for i in r["ids"]}
        assert {w["track"]: w["truth"] for w in r["wrong"]} == {i: c for i, c in truths.items() if c != r["class"]}
    summary = as_accepted_summary(records, undone=set())
    assert summary["all"]["tracks"] == sum(r["n_tracks"] for r in records)
