"""Stitches: ingest stores the fragment links between tracks, an operator confirms or rejects
them, and a confirmed stitch's fragment pairs are verified constraints (real pipeline, simulated)."""

from __future__ import annotations

import json

import pytest

from tests.app.factories import ingest_through_api, simulated_campus


@pytest.fixture(scope="module")
def simulated(tmp_path_factory):
    return simulated_campus(tmp_path_factory, frames=6, seed=3)


def _ingest(client, factory, settings, db, simulated):
    seq, job, _admin = ingest_through_api(client, factory, settings, db, simulated)
    return seq["id"], job["result"], factory.user("operator")


def _verified(client, op, seq):
    r = client.get("/api/v1/exports/constraints", params={"sequence_id": seq}, headers=op.headers)
    assert r.status_code == 200, r.text
    return [json.loads(line) for line in r.text.splitlines() if line]


def _accept(client, op, track_id):
    version = client.get(f"/api/v1/tracks/{track_id}", headers=op.headers).json()["version"]
    r = client.post(f"/api/v1/tracks/{track_id}/accept", json={"version": version}, headers=op.headers)
    assert r.status_code == 200, r.text


def test_stitches_ingest_lists_them_pending_with_their_links(client, factory, settings, db, simulated):
    seq, result, op = _ingest(client, factory, settings, db, simulated)
    r = client.get("/api/v1/stitches", params={"sequence_id": seq, "limit": 1000}, headers=op.headers)
    assert r.status_code == 200, r.text
    body = r.json()
    assert body["total"] == result["stitches"] == len(body["items"]) > 0
    assert sum(st["links"] for st in body["items"]) == result["fragments"]
    for st in body["items"]:
        assert st["track_a_id"] < st["track_b_id"] and st["status"] == "pending" and st["version"] == 1
        assert st["links"] >= 1 and 0.3 <= st["share"] <= 1.0
    one = body["items"][0]
    by_track = client.get("/api/v1/stitches", params={"track_id": one["track_b_id"]}, headers=op.headers).json()
    assert one["id"] in {st["id"] for st in by_track["items"]}


def test_stitches_confirmed_between_accepted_tracks_give_verified_constraints(client, factory, settings, db, simulated):
    seq, _, op = _ingest(client, factory, settings, db, simulated)
    st = client.get("/api/v1/stitches", params={"sequence_id": seq}, headers=op.headers).json()["items"][0]
    a, b = st["track_a_id"], st["track_b_id"]
    _accept(client, op, a)
    _accept(client, op, b)
    track_pairs = _verified(client, op, seq)
    assert track_pairs and {p["track_id"] for p in track_pairs} <= {a, b}

    r = client.post(f"/api/v1/stitches/{st['id']}/confirm", json={"version": 1}, headers=op.headers)
    assert r.status_code == 200, r.text
    assert r.json()["status"] == "confirmed" and r.json()["version"] == 2 and r.json()["decided_by_id"] == op.id
    after = _verified(client, op, seq)
    added = [p for p in after if p not in track_pairs]
    assert len(added) == st["links"] and all(p["verified"] for p in added)
    assert {p["track_id"] for p in added} <= {a, b}
    # the automatic export held the fragment pairs before too
    auto = client.get("/api/v1/exports/constraints", params={"sequence_id": seq, "verified_only": False}, headers=op.headers)
    assert len(auto.text.splitlines()) >= len(after)

    # a stale decision changes nothing; rejecting with the new version removes the pairs again
    assert client.post(f"/api/v1/stitches/{st['id']}/reject", json={"version": 1}, headers=op.headers).status_code == 409
    assert len(_verified(client, op, seq)) == len(after)
    r = client.post(f"/api/v1/stitches/{st['id']}/reject", json={"version": 2}, headers=op.headers)
    assert r.status_code == 200 and r.json()["status"] == "rejected"
    assert _verified(client, op, seq) == track_pairs


def test_stitches_unknown_id_is_404_and_bad_body_422(client, factory, settings, db, simulated):
    seq, _, op = _ingest(client, factory, settings, db, simulated)
    assert client.get("/api/v1/stitches/999999", headers=op.headers).status_code == 404
    assert client.post("/api/v1/stitches/999999/confirm", json={"version": 1}, headers=op.headers).status_code == 404
    st = client.get("/api/v1/stitches", params={"sequence_id": seq}, headers=op.headers).json()["items"][0]
    assert client.post(f"/api/v1/stitches/{st['id']}/confirm", json={}, headers=op.headers).status_code == 422
    assert client.post(f"/api/v1/stitches/{st['id']}/confirm", json={"version": 0}, headers=op.headers).status_code == 422
    assert client.get(f"/api/v1/stitches/{st['id']}", headers=op.headers).json()["status"] == "pending"
