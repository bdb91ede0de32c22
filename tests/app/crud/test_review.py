from __future__ import annotations

import time

from sqlalchemy import update

from app.models import Sequence


def _next(client, caller, **params):
    return client.post("/api/v1/review/next", params=params, headers=caller.headers)


def test_review_two_operators_get_different_tracks(client, factory):
    factory.ingested_sequence(n_objects=3)
    a, b = factory.user(), factory.user()
    ta, tb = _next(client, a).json(), _next(client, b).json()
    assert ta["id"] != tb["id"]


def test_review_own_lease_is_returned_again(client, factory):
    factory.ingested_sequence(n_objects=3)
    a = factory.user()
    assert _next(client, a).json()["id"] == _next(client, a).json()["id"]


def test_review_action_frees_caller_for_the_next_track(client, factory):
    factory.ingested_sequence(n_objects=3)
    a = factory.user()
    t = _next(client, a).json()
    client.post(f"/api/v1/tracks/{t['id']}/accept", json={"version": t["version"]}, headers=a.headers)
    assert _next(client, a).json()["id"] != t["id"]


def test_review_expired_lease_frees_the_track(client, factory, settings):
    factory.ingested_sequence(n_objects=1)
    a, b = factory.user(), factory.user()
    settings.review_lease_seconds = 2.0  # long enough for b's first request on a loaded machine
    t = _next(client, a).json()
    assert _next(client, b).status_code == 204
    time.sleep(2.1)
    assert _next(client, b).json()["id"] == t["id"]


def test_review_nothing_left_is_204(client, factory):
    factory.ingested_sequence(n_objects=1)
    a = factory.user()
    t = _next(client, a).json()
    client.post(f"/api/v1/tracks/{t['id']}/discard", json={"version": 1}, headers=a.headers)
    assert _next(client, a).status_code == 204


def test_review_skips_sequences_still_ingesting(client, factory, db):
    seq = factory.ingested_sequence(n_objects=2)
    with db.write() as s:
        s.execute(update(Sequence).where(Sequence.id == seq).values(status="ingesting"))
        s.commit()
    assert _next(client, factory.user()).status_code == 204


def test_review_release_gives_the_track_back(client, factory):
    factory.ingested_sequence(n_objects=1)
    a, b = factory.user(), factory.user()
    t = _next(client, a).json()
    assert client.post(f"/api/v1/review/{t['id']}/release", headers=a.headers).status_code == 204
    assert _next(client, b).json()["id"] == t["id"]


def test_review_next_passes_over_excluded_tracks(client, factory):
    # one user in two viewer tabs: the second tab excludes the first tab's track, own lease included
    factory.ingested_sequence(n_objects=3)
    a = factory.user()
    first = _next(client, a).json()
    second = _next(client, a, exclude=[first["id"]]).json()
    third = _next(client, a, exclude=[first["id"], second["id"]]).json()
    assert len({first["id"], second["id"], third["id"]}) == 3
    assert _next(client, a, exclude=[first["id"], second["id"], third["id"]]).status_code == 204


def test_review_lease_of_a_chosen_track_keeps_the_queue_off_it(client, factory):
    seq = factory.ingested_sequence(n_objects=1)
    a, b = factory.user(name="ann"), factory.user()
    tid = factory.track_ids(seq)[0]
    r = client.post(f"/api/v1/review/{tid}/lease", headers=a.headers)
    assert r.status_code == 200 and r.json()["id"] == tid
    assert client.post(f"/api/v1/review/{tid}/lease", headers=a.headers).status_code == 200  # own: renewed
    held = client.post(f"/api/v1/review/{tid}/lease", headers=b.headers)
    assert held.status_code == 409 and "ann" in held.json()["detail"]
    assert _next(client, b).status_code == 204  # the only track is held: the queue has nothing for b
    assert client.post("/api/v1/review/999999/lease", headers=a.headers).status_code == 404


def test_review_lease_of_a_reviewed_track_is_not_needed(client, factory):
    factory.ingested_sequence(n_objects=1)
    a, b = factory.user(), factory.user()
    t = _next(client, a).json()
    client.post(f"/api/v1/tracks/{t['id']}/accept", json={"version": t["version"]}, headers=a.headers)
    r = client.post(f"/api/v1/review/{t['id']}/lease", headers=b.headers)
    assert r.status_code == 200 and r.json()["status"] == "accepted"


def test_review_queue_serves_priority_first_or_size_first(client, factory, db):
    from app.models import Track

    seq = factory.ingested_sequence(n_objects=3)
    ids = factory.track_ids(seq)
    with db.write() as s:  # the smallest track has the highest priority (the model is unsure of it)
        for tid, prio, n in zip(ids, (1.0, 5.0, 3.0), (300, 100, 200), strict=True):
            s.execute(update(Track).where(Track.id == tid).values(priority=prio, n_points=n))
        s.commit()
    assert _next(client, factory.user()).json()["id"] == ids[1]
    assert _next(client, factory.user(), order="size").json()["id"] == ids[0]


def test_review_every_declared_action_is_a_stored_action_with_a_route_or_the_repairs_undo(client):
    """A review action declared in `crud.REVIEW_ACTIONS` is one the events table accepts and has
    its POST route (undo's is the repair's)."""
    from app import crud
    from app.models import ACTIONS

    assert set(crud.REVIEW_ACTIONS) <= set(ACTIONS)
    paths = client.get("/api/v1/openapi.json").json()["paths"]
    for name in crud.REVIEW_ACTIONS:
        assert "post" in paths[f"/api/v1/tracks/{{track_id}}/{name}"], name
