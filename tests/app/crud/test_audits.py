"""The quality stage (issue 23): sample accepted tracks into an audit queue, agree or correct,
agreement per operator and class in /exports/stats."""

from __future__ import annotations


def _label_all(client, factory, seq, op, label="car"):
    for tid in factory.track_ids(seq):
        track = client.get(f"/api/v1/tracks/{tid}", headers=op.headers).json()
        r = client.post(f"/api/v1/tracks/{tid}/label", json={"version": track["version"], "label": label}, headers=op.headers)
        assert r.status_code == 200, r.text


def test_audits_operator_cannot_sample_or_decide(client, factory):
    op = factory.user("operator")
    assert client.post("/api/v1/audits/sample", json={"n": 1}, headers=op.headers).status_code == 403
    assert client.get("/api/v1/audits", headers=op.headers).status_code == 403


def test_audits_sample_takes_accepted_tracks_once(client, factory):
    seq = factory.ingested_sequence(n_objects=4)
    op, reviewer = factory.user("operator", "ann"), factory.user("reviewer")
    _label_all(client, factory, seq, op)
    first = client.post("/api/v1/audits/sample", json={"n": 3, "seed": 1}, headers=reviewer.headers).json()
    assert len(first) == 3 and all(a["operator_id"] == op.id and a["label"] == "car" for a in first)
    second = client.post("/api/v1/audits/sample", json={"n": 3}, headers=reviewer.headers).json()
    assert len(second) == 1 and second[0]["track_id"] not in {a["track_id"] for a in first}


def test_audits_agree_and_correct_give_agreement_per_operator_and_class(client, factory, db):
    seq = factory.ingested_sequence(n_objects=4)
    op, auditor = factory.user("operator", "ann"), factory.user("admin", "boss")
    _label_all(client, factory, seq, op)
    audits = client.post("/api/v1/audits/sample", json={"n": 4}, headers=auditor.headers).json()
    for a in audits[:3]:
        assert client.post(f"/api/v1/audits/{a['id']}/agree", headers=auditor.headers).json()["status"] == "agreed"
    r = client.post(f"/api/v1/audits/{audits[3]['id']}/correct", json={"label": "person"}, headers=auditor.headers)
    assert r.json()["status"] == "corrected" and r.json()["answer_label"] == "person"
    assert factory.track(audits[3]["track_id"]).label == "person"  # the correction is applied
    events = client.get(f"/api/v1/tracks/{audits[3]['track_id']}/events", headers=auditor.headers).json()
    assert events[-1]["action"] == "label" and events[-1]["user_id"] == auditor.id
    stats = client.get("/api/v1/exports/stats", headers=op.headers).json()["audit"]
    assert stats["per_operator"]["ann"] == {"audited": 4, "agreed": 3, "agreement": 0.75}
    assert stats["per_class"]["car"]["agreement"] == 0.75 and stats["queued"] == 0
    assert client.post(f"/api/v1/audits/{audits[0]['id']}/agree", headers=auditor.headers).status_code == 409
