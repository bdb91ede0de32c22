"""Leases are enforced (issue 23, defect 4): while one operator holds a track's lease, nobody else
changes it; admins override explicitly; the holder's actions renew the lease."""

from __future__ import annotations

from datetime import timedelta

from app.models import Track, utcnow


def _act(client, caller, track_id, action, version, params=None, **body):
    return client.post(
        f"/api/v1/tracks/{track_id}/{action}", json={"version": version, **body}, headers=caller.headers, params=params
    )


def _leased(client, factory):
    factory.ingested_sequence(n_objects=3)
    first, second = factory.user("operator", "ann"), factory.user("operator", "bob")
    track = client.post("/api/v1/review/next", headers=first.headers).json()
    return first, second, track


def test_leases_second_operator_truncate_is_409_naming_the_holder(client, factory):
    first, second, track = _leased(client, factory)
    r = _act(client, second, track["id"], "truncate", track["version"], start=track["first_frame"], end=track["first_frame"])
    assert r.status_code == 409 and "ann" in r.json()["detail"]
    assert factory.track(track["id"]).version == track["version"]


def test_leases_second_operator_cannot_label_then_holder_acts(client, factory):
    first, second, track = _leased(client, factory)
    for action, body in (("label", {"label": "car"}), ("accept", {}), ("discard", {}), ("undo", {})):
        assert _act(client, second, track["id"], action, track["version"], **body).status_code == 409, action
    assert _act(client, first, track["id"], "label", track["version"], label="person").status_code == 200
    assert factory.track(track["id"]).label == "person"


def test_leases_admin_override_is_explicit(client, factory):
    first, _, track = _leased(client, factory)
    admin = factory.user("admin")
    assert _act(client, admin, track["id"], "accept", track["version"]).status_code == 409
    r = _act(client, admin, track["id"], "accept", track["version"], params={"override_lease": "true"})
    assert r.status_code == 200 and r.json()["status"] == "accepted"


def test_leases_operator_override_is_403(client, factory):
    first, second, track = _leased(client, factory)
    r = _act(client, second, track["id"], "accept", track["version"], params={"override_lease": "true"})
    assert r.status_code == 403


def test_leases_holder_action_renews_the_lease(client, factory, db, settings):
    first, _, track = _leased(client, factory)
    with db.write() as s:  # almost expired
        s.get(Track, track["id"]).lease_expires_at = utcnow() + timedelta(seconds=2)
        s.commit()
    before = utcnow()
    r = _act(client, first, track["id"], "truncate", track["version"], start=track["first_frame"], end=track["last_frame"])
    assert r.status_code == 200
    expires = factory.track(track["id"]).lease_expires_at
    assert expires >= before + timedelta(seconds=settings.review_lease_seconds - 5)


def test_leases_expired_lease_binds_nobody(client, factory, db):
    first, second, track = _leased(client, factory)
    with db.write() as s:
        s.get(Track, track["id"]).lease_expires_at = utcnow() - timedelta(seconds=1)
        s.commit()
    assert _act(client, second, track["id"], "accept", track["version"]).status_code == 200


def test_leases_truncate_updates_points_and_mean_range(client, factory, db):
    # defect 9: n_points and mean_range follow the kept range
    first, _, track = _leased(client, factory)
    r = _act(client, first, track["id"], "truncate", track["version"], start=track["last_frame"], end=track["last_frame"])
    assert r.status_code == 200
    body = r.json()
    from sqlalchemy import select

    from app.models import Segment

    with db.read() as s:
        seg = s.scalars(select(Segment).where(Segment.track_id == track["id"], Segment.frame_index == track["last_frame"])).one()
    assert body["length"] == 1 and body["n_points"] == seg.n_points and body["n_points"] < track["n_points"]
    assert abs(body["mean_range"] - seg.range) < 1e-6


def test_leases_stitch_decision_on_a_leased_track_is_409(client, factory, db):
    from sqlalchemy import select

    from app.models import Stitch

    first, second, track = _leased(client, factory)
    with db.write() as s:
        other = s.scalars(select(Track.id).where(Track.id != track["id"]).order_by(Track.id)).first()
        a, b = sorted((track["id"], other))
        st = Stitch(sequence_id=track["sequence_id"], track_a_id=a, track_b_id=b, links=1, share=0.5)
        s.add(st)
        s.commit()
        stitch_id = st.id
    r = client.post(f"/api/v1/stitches/{stitch_id}/confirm", json={"version": 1}, headers=second.headers)
    assert r.status_code == 409 and "ann" in r.json()["detail"]
    assert client.post(f"/api/v1/stitches/{stitch_id}/confirm", json={"version": 1}, headers=first.headers).status_code == 200


def test_leases_every_409_of_a_lease_reads_the_same(client, factory):
    """The action routes and `POST /review/{id}/lease` refuse another user's lease in one format."""
    import re

    first, second, track = _leased(client, factory)
    by_action = _act(client, second, track["id"], "accept", track["version"]).json()["detail"]
    by_lease = client.post(f"/api/v1/review/{track['id']}/lease", headers=second.headers).json()["detail"]
    pattern = rf"^track {track['id']} is leased to ann until \S+Z; an admin may override with override_lease=true$"
    assert re.match(pattern, by_action) and re.match(pattern, by_lease), (by_action, by_lease)


def test_leases_next_writes_a_new_lease_once_and_renews_the_callers_own(client, factory, db):
    from sqlalchemy import event

    factory.ingested_sequence(n_objects=3)
    ann = factory.user("operator", "ann")
    updates: list[str] = []

    def count(_conn, _cursor, statement, *_args) -> None:  # noqa: ANN001
        if statement.lstrip().upper().startswith("UPDATE TRACKS"):
            updates.append(statement)

    event.listen(db.engine, "before_cursor_execute", count)
    try:
        first = client.post("/api/v1/review/next", headers=ann.headers).json()
        assert len(updates) == 1  # the conditional update that wins the lease; nothing flushed after it
        granted = factory.track(first["id"]).lease_expires_at
        again = client.post("/api/v1/review/next", headers=ann.headers).json()
        assert again["id"] == first["id"] and len(updates) == 2
        assert factory.track(first["id"]).lease_expires_at > granted
    finally:
        event.remove(db.engine, "before_cursor_execute", count)
