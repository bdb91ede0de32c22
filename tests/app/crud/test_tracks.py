from __future__ import annotations

import io

import numpy as np
from sqlalchemy import func, select

from app import crud
from app.models import AnnotationEvent, Label, Track


def _setup(factory, **kw):
    seq = factory.ingested_sequence(**kw)
    return seq, factory.user("operator"), factory.track_ids(seq)


def _act(client, caller, track_id, action, version, **body):
    return client.post(f"/api/v1/tracks/{track_id}/{action}", json={"version": version, **body}, headers=caller.headers)


def test_tracks_list_paginates_with_total(client, factory):
    seq, op, ids = _setup(factory, n_objects=7)
    r = client.get("/api/v1/tracks", params={"sequence_id": seq, "limit": 3, "offset": 3}, headers=op.headers)
    body = r.json()
    assert body["total"] == 7 and [t["id"] for t in body["items"]] == ids[3:6]


def test_tracks_list_filters_by_length(client, factory):
    # objects o start at frame o % 3 of 6: lengths 6, 5, 4, 6, 5, 4
    seq, op, _ = _setup(factory, n_objects=6)
    r = client.get("/api/v1/tracks", params={"min_length": 5, "max_length": 5}, headers=op.headers)
    assert [t["length"] for t in r.json()["items"]] == [5, 5]


def test_tracks_list_sorts_descending(client, factory):
    seq, op, _ = _setup(factory, n_objects=6)
    r = client.get("/api/v1/tracks", params={"sort": "-length"}, headers=op.headers)
    lengths = [t["length"] for t in r.json()["items"]]
    assert lengths == sorted(lengths, reverse=True)


def test_tracks_list_pages_follow_key_then_id_with_nulls_last_both_ways(client, factory, db):
    # lengths tie (6, 5, 4, 6, 5, 4): pages must follow (key, id) exactly, in both directions, and
    # tracks without a confidence come last either way
    seq, op, ids = _setup(factory, n_objects=6)
    with db.write() as s:
        for i, conf in enumerate([0.5, None, 0.2, 0.5, None, 0.9]):
            s.get(Track, ids[i]).predicted_confidence = conf
        s.commit()
    with db.read() as s:
        rows = {t.id: (t.length, t.predicted_confidence) for t in s.scalars(select(Track).where(Track.id.in_(ids)))}
    for sort, key in (("length", 0), ("confidence", 1)):
        for desc in (False, True):
            have = [t["id"] for off in (0, 2, 4) for t in client.get(
                "/api/v1/tracks", params={"sort": ("-" if desc else "") + sort, "limit": 2, "offset": off},
                headers=op.headers).json()["items"]]
            known = sorted((i for i in ids if rows[i][key] is not None), key=lambda i: (rows[i][key], i), reverse=desc)
            nulls = sorted((i for i in ids if rows[i][key] is None), reverse=desc)
            assert have == known + nulls, (sort, desc)


def test_tracks_list_filters_status_and_label(client, factory):
    seq, op, ids = _setup(factory)
    _act(client, op, ids[0], "label", 1, label="car")
    _act(client, op, ids[1], "discard", 1)
    by_status = client.get("/api/v1/tracks", params={"status": "discarded"}, headers=op.headers).json()
    by_label = client.get("/api/v1/tracks", params={"label": "car"}, headers=op.headers).json()
    assert [t["id"] for t in by_status["items"]] == [ids[1]] and [t["id"] for t in by_label["items"]] == [ids[0]]


def test_tracks_list_filters_predicted_class_and_confidence(client, factory, db):
    seq, op, ids = _setup(factory)
    with db.write() as s:
        for i, (cls, conf) in enumerate([("car", 0.9), ("car", 0.4), ("person", 0.95)]):
            t = s.get(Track, ids[i])
            t.predicted_class, t.predicted_confidence = cls, conf
        s.commit()
    r = client.get("/api/v1/tracks", params={"predicted_class": "car", "min_confidence": 0.5}, headers=op.headers)
    assert [t["id"] for t in r.json()["items"]] == [ids[0]]


def test_tracks_list_unknown_filter_class_is_422(client, factory):
    op = factory.user()
    assert client.get("/api/v1/tracks", params={"label": "dragon"}, headers=op.headers).status_code == 422


def test_tracks_detail_lists_segments_with_sample_urls(client, factory):
    seq, op, ids = _setup(factory, n_frames=5)
    d = client.get(f"/api/v1/tracks/{ids[0]}", headers=op.headers).json()
    assert [s["frame_index"] for s in d["segments"]] == [0, 1, 2, 3, 4]
    assert all(s["sample_url"] for s in d["segments"])


def test_tracks_sample_is_png(client, factory):
    import cv2

    seq, op, ids = _setup(factory)
    url = client.get(f"/api/v1/tracks/{ids[0]}", headers=op.headers).json()["segments"][0]["sample_url"]
    r = client.get(url, headers=op.headers)
    assert r.headers["content-type"] == "image/png"
    img = cv2.imdecode(np.frombuffer(r.content, np.uint8), cv2.IMREAD_UNCHANGED)
    assert img.shape == (8, 32)  # 4 channels of 8x8 side by side


def test_tracks_accept_bumps_version_and_records_operator(client, factory, db):
    seq, op, ids = _setup(factory)
    r = _act(client, op, ids[0], "accept", 1)
    assert r.status_code == 200 and r.json()["status"] == "accepted" and r.json()["version"] == 2
    with db.read() as s:
        ev = s.scalars(select(AnnotationEvent).where(AnnotationEvent.track_id == ids[0])).one()
    assert (ev.user_id, ev.action, ev.before["status"], ev.after["status"]) == (op.id, "accept", "pending", "accepted")


def test_tracks_stale_version_is_409_and_changes_nothing(client, factory, db):
    seq, op, ids = _setup(factory)
    assert _act(client, op, ids[0], "accept", 1).status_code == 200
    r = _act(client, op, ids[0], "discard", 1)
    assert r.status_code == 409
    t = factory.track(ids[0])
    with db.read() as s:
        n_events = s.scalar(select(func.count()).where(AnnotationEvent.track_id == ids[0]))
    assert (t.status, t.version, n_events) == ("accepted", 2, 1)


def test_tracks_label_unknown_class_is_422(client, factory):
    seq, op, ids = _setup(factory)
    assert _act(client, op, ids[0], "label", 1, label="ground").status_code == 422
    assert factory.track(ids[0]).version == 1


def test_tracks_label_accepts_and_materialises_labels(client, factory, db):
    seq, op, ids = _setup(factory, n_frames=6)
    r = _act(client, op, ids[0], "label", 1, label="person")
    assert r.json()["status"] == "accepted" and r.json()["label"] == "person"
    with db.read() as s:
        labels = s.scalars(select(Label.class_name).where(Label.track_id == ids[0])).all()
    assert labels == ["person"] * 6


def test_tracks_truncate_outside_range_is_409(client, factory):
    # well-formed (the schema takes it), ruled out by the track's frames: 409, as the contract says
    seq, op, ids = _setup(factory, n_frames=6)
    assert _act(client, op, ids[0], "truncate", 1, start=2, end=9).status_code == 409
    assert _act(client, op, ids[0], "truncate", 1, start=4, end=3).status_code == 409


def test_tracks_truncate_keeps_range_and_recounts(client, factory, db):
    seq, op, ids = _setup(factory, n_frames=6)
    _act(client, op, ids[0], "label", 1, label="car")
    r = _act(client, op, ids[0], "truncate", 2, start=1, end=3)
    assert (r.json()["keep_start"], r.json()["keep_end"], r.json()["length"], r.json()["n_samples"]) == (1, 3, 3, 3)
    with db.read() as s:
        assert s.scalar(select(func.count()).where(Label.track_id == ids[0])) == 3


def test_tracks_undo_reverts_callers_last_action(client, factory):
    seq, op, ids = _setup(factory)
    _act(client, op, ids[0], "label", 1, label="car")
    _act(client, op, ids[0], "truncate", 2, start=1, end=3)
    r = _act(client, op, ids[0], "undo", 3)
    assert (r.json()["keep_start"], r.json()["label"], r.json()["version"]) == (0, "car", 4)
    r = _act(client, op, ids[0], "undo", 4)
    assert (r.json()["status"], r.json()["label"]) == ("pending", None)


def test_tracks_undo_without_own_action_is_409(client, factory):
    seq, op, ids = _setup(factory)
    other = factory.user("operator")
    _act(client, other, ids[0], "accept", 1)
    assert _act(client, op, ids[0], "undo", 2).status_code == 409


def test_tracks_state_rebuilds_from_events(client, factory, db):
    seq, op, ids = _setup(factory)
    other = factory.user("operator")
    _act(client, op, ids[0], "label", 1, label="bush")
    _act(client, other, ids[0], "truncate", 2, start=1, end=4)
    _act(client, op, ids[0], "discard", 3)
    _act(client, op, ids[0], "undo", 4)
    with db.read() as s:
        t = s.get(Track, ids[0])
        assert crud.rebuild_review_state(s, t) == crud.review_state(t)
        assert crud.review_state(t) == {"status": "accepted", "label": "bush", "keep_start": 1, "keep_end": 4,
                                        "label_source": "review"}


def test_tracks_action_on_unknown_track_is_404(client, factory):
    op = factory.user()
    assert _act(client, op, 999, "accept", 1).status_code == 404


def test_tracks_frame_payload_is_npz_with_track_per_point(client, factory):
    seq, op, ids = _setup(factory, n_frames=3, n_objects=2)
    frames = client.get(f"/api/v1/sequences/{seq}/frames", headers=op.headers).json()
    assert frames["total"] == 3
    r = client.get(f"/api/v1/frames/{frames['items'][0]['id']}/payload", headers=op.headers)
    z = np.load(io.BytesIO(r.content))
    assert z["points"].dtype == np.float32 and z["points"].shape[1] == 3 and z["track"].dtype == np.int32
    seg, track = z["segment"], z["track"]
    assert set(np.unique(track[seg == 0])) == {ids[0]} and set(np.unique(track[seg < 0])) == {0}


def test_tracks_list_filters_by_ids(client, factory):
    seq, op, ids = _setup(factory, n_objects=5)
    r = client.get("/api/v1/tracks", params={"ids": [ids[3], ids[1], 999_999]}, headers=op.headers)
    assert [t["id"] for t in r.json()["items"]] == [ids[1], ids[3]]
