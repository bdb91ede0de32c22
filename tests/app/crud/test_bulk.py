"""Bulk accept: one action labels every confident prediction of a class; undo, audits, stats."""

from __future__ import annotations

from sqlalchemy import select, update

from app import crud
from app.models import AnnotationEvent, Job, Label, Track


def _predict(db, seq, classes: dict[int, tuple[str, float]]) -> None:
    with db.write() as s:
        for tid, (cls, conf) in classes.items():
            s.execute(update(Track).where(Track.id == tid).values(predicted_class=cls, predicted_confidence=conf))
        s.commit()


def _bulk(client, caller, seq, cls="bush", conf=0.9, **kw):
    body = {"class_name": cls, "min_confidence": conf, **kw}
    return client.post(f"/api/v1/sequences/{seq}/bulk-accept", json=body, headers=caller.headers)


def test_bulk_accept_labels_every_confident_prediction_of_the_class(client, factory, db):
    seq = factory.ingested_sequence(n_objects=4)
    t = factory.track_ids(seq)
    _predict(db, seq, {t[0]: ("bush", 0.95), t[1]: ("bush", 0.91), t[2]: ("bush", 0.5), t[3]: ("car", 0.99)})
    op = factory.user()
    preview = client.get(f"/api/v1/sequences/{seq}/bulk-accept/preview",
                         params={"class_name": "bush", "min_confidence": 0.9}, headers=op.headers).json()
    assert preview["tracks"] == 2 and set(preview["largest_track_ids"]) == {t[0], t[1]}
    r = _bulk(client, op, seq, expected_tracks=2)
    assert r.status_code == 200, r.text
    assert r.json()["n_tracks"] == 2
    got = {i: (factory.track(i).status, factory.track(i).label, factory.track(i).label_source) for i in t}
    assert got[t[0]] == got[t[1]] == ("accepted", "bush", "bulk")
    assert got[t[2]][0] == got[t[3]][0] == "pending"
    with db.read() as s:
        sources = set(s.scalars(select(Label.source).where(Label.track_id.in_([t[0], t[1]]))).all())
        assert sources == {"bulk"}
        assert crud.operation_count(s, seq) == 1  # one request, whatever the tracks
    stats = client.get("/api/v1/exports/stats", params={"sequence_id": seq}, headers=op.headers).json()
    assert stats["tracks_accepted_by_source"] == {"bulk": 2} and stats["bulk_actions"] == 1


def test_bulk_accept_leaves_out_tracks_smaller_than_any_it_was_checked_on(client, factory, db):
    seq = factory.ingested_sequence(n_objects=4)
    t = sorted(factory.track_ids(seq), key=lambda i: factory.track(i).n_points)
    sizes = [factory.track(i).n_points for i in t]
    assert sizes[0] < sizes[1] < sizes[3], sizes
    _predict(db, seq, {i: ("bush", 0.97) for i in t})
    # the newest assist run held out reviewed tracks of sizes[1] and more (and a bigger car)
    held = {"truth": ["bush", "bush", "car"], "predicted": ["bush", "bush", "car"], "confidence": [0.99, 0.98, 0.99],
            "points": [sizes[1], sizes[3] + 100, 5]}
    with db.write() as s:
        s.add(Job(type="assist", status="succeeded", params={"sequence_id": seq}, result={"held_out": held}))
        s.commit()
    op = factory.user()
    preview = client.get(f"/api/v1/sequences/{seq}/bulk-accept/preview",
                         params={"class_name": "bush", "min_confidence": 0.95}, headers=op.headers).json()
    assert preview["min_points"] == sizes[1] and preview["held_out_precision"] == 1.0 and preview["held_out_tracks"] == 2
    assert preview["tracks"] == 3 and t[0] not in preview["largest_track_ids"]  # smaller than any it was checked on
    r = _bulk(client, op, seq, conf=0.95, expected_tracks=3)
    assert r.status_code == 200, r.text
    assert factory.track(t[0]).status == "pending" and all(factory.track(i).label_source == "bulk" for i in t[1:])


def test_bulk_accept_refuses_a_count_other_than_the_preview(client, factory, db):
    seq = factory.ingested_sequence(n_objects=3)
    t = factory.track_ids(seq)
    _predict(db, seq, {t[0]: ("bush", 0.95)})
    op = factory.user()
    assert _bulk(client, op, seq, expected_tracks=2).status_code == 409
    assert factory.track(t[0]).status == "pending"


def test_bulk_accept_leaves_tracks_leased_to_someone_else(client, factory, db):
    seq = factory.ingested_sequence(n_objects=2)
    a, b = factory.user(), factory.user()
    leased = client.post("/api/v1/review/next", headers=a.headers).json()["id"]
    _predict(db, seq, {i: ("car", 0.99) for i in factory.track_ids(seq)})
    assert _bulk(client, b, seq, cls="car").json()["n_tracks"] == 1
    assert factory.track(leased).status == "pending"


def test_bulk_undo_reverts_unchanged_tracks_in_one_action(client, factory, db):
    seq = factory.ingested_sequence(n_objects=3)
    t = factory.track_ids(seq)
    _predict(db, seq, {i: ("bush", 0.99) for i in t})
    op = factory.user()
    bulk = _bulk(client, op, seq).json()
    # one track relabelled by its operator after the bulk keeps the newer class
    client.post(f"/api/v1/tracks/{t[0]}/label", json={"version": factory.track(t[0]).version, "label": "car"},
                headers=op.headers)
    r = client.post(f"/api/v1/bulk-actions/{bulk['id']}/undo", headers=op.headers)
    assert r.status_code == 200 and r.json()["undone_at"] is not None
    assert (factory.track(t[0]).status, factory.track(t[0]).label) == ("accepted", "car")
    for i in t[1:]:
        tr = factory.track(i)
        assert (tr.status, tr.label, tr.label_source) == ("pending", None, None)
    with db.read() as s:
        assert s.scalar(select(Label.id).where(Label.track_id.in_(t[1:]))) is None
        assert crud.rebuild_review_state(s, factory.track(t[1])) == crud.review_state(factory.track(t[1]))
        assert crud.operation_count(s, seq) == 3  # bulk, label, bulk undo
    assert client.post(f"/api/v1/bulk-actions/{bulk['id']}/undo", headers=op.headers).status_code == 409


def test_bulk_single_track_undoes_like_any_action(client, factory, db):
    seq = factory.ingested_sequence(n_objects=2)
    t = factory.track_ids(seq)
    _predict(db, seq, {i: ("trunk", 0.97) for i in t})
    op = factory.user()
    _bulk(client, op, seq, cls="trunk")
    r = client.post(f"/api/v1/tracks/{t[0]}/undo", json={"version": factory.track(t[0]).version}, headers=op.headers)
    assert r.status_code == 200, r.text
    assert factory.track(t[0]).status == "pending" and factory.track(t[1]).label_source == "bulk"
    with db.read() as s:
        actions = s.scalars(select(AnnotationEvent.action).where(AnnotationEvent.track_id == t[0])
                            .order_by(AnnotationEvent.id)).all()
        assert actions == ["bulk_accept", "undo"]


def test_bulk_audit_measures_error_per_class_with_an_interval(client, factory, db):
    seq = factory.ingested_sequence(n_objects=4)
    t = factory.track_ids(seq)
    _predict(db, seq, {i: ("bush", 0.99) for i in t[:3]})
    op, reviewer = factory.user(), factory.user("reviewer")
    client.post(f"/api/v1/tracks/{t[3]}/label", json={"version": 1, "label": "car"}, headers=op.headers)
    _bulk(client, op, seq)
    audits = client.post("/api/v1/audits/sample", json={"n": 10, "sequence_id": seq, "source": "bulk"},
                         headers=reviewer.headers).json()
    assert sorted(a["track_id"] for a in audits) == t[:3] and {a["source"] for a in audits} == {"bulk"}
    client.post(f"/api/v1/audits/{audits[0]['id']}/correct", json={"label": "building"}, headers=reviewer.headers)
    for a in audits[1:]:
        client.post(f"/api/v1/audits/{a['id']}/agree", headers=reviewer.headers)
    bulk = client.get("/api/v1/exports/stats", params={"sequence_id": seq}, headers=op.headers).json()["audit"]["bulk"]
    row = bulk["per_class"]["bush"]
    assert (row["audited"], row["corrected"]) == (3, 1)
    assert row["ci95"][0] < 1 / 3 < row["ci95"][1]
    assert bulk["overall"]["error"] == round(1 / 3, 4)


def test_bulk_undone_bulk_leaves_the_audit_estimate(client, factory, db):
    seq = factory.ingested_sequence(n_objects=3)
    t = factory.track_ids(seq)
    _predict(db, seq, {i: ("bush", 0.99) for i in t})
    op, reviewer = factory.user(), factory.user("reviewer")
    bulk = _bulk(client, op, seq).json()
    audits = client.post("/api/v1/audits/sample", json={"n": 1, "sequence_id": seq, "source": "bulk"},
                         headers=reviewer.headers).json()
    client.post(f"/api/v1/audits/{audits[0]['id']}/discard", headers=reviewer.headers)  # no object: discarded
    assert factory.track(audits[0]["track_id"]).status == "discarded"
    stats = lambda: client.get("/api/v1/exports/stats", params={"sequence_id": seq}, headers=op.headers).json()  # noqa: E731
    assert stats()["audit"]["bulk"]["overall"]["corrected"] == 1
    client.post(f"/api/v1/bulk-actions/{bulk['id']}/undo", headers=op.headers)
    assert stats()["audit"]["bulk"]["overall"]["audited"] == 0
