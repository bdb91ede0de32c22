"""The versions that keep the viewer's caches true: a frame payload's ETag follows its artifact,
the change feed lists what a split / undo / accept changed, points progress counts points, and
split -> undo -> split never hands out an id twice (an old edit then gets 404 or 409)."""

from __future__ import annotations

import pytest

from tests.app.fakes import fake_pipeline

HALF = {"kind": "halfspace", "normal": [1.0, 0.0, 0.0], "offset": 0.0}


@pytest.fixture(autouse=True)
def fakes():
    with fake_pipeline():
        yield


def _post(client, caller, path, body, status=200):
    r = client.post(f"/api/v1{path}", json=body, headers=caller.headers)
    assert r.status_code == status, r.text
    return r.json()


def _get(client, caller, path, **params):
    r = client.get(f"/api/v1{path}", params=params, headers=caller.headers)
    assert r.status_code == 200, r.text
    return r


def _frame_of(client, op, track_id):
    return _get(client, op, f"/tracks/{track_id}").json()["segments"][0]["frame_id"]


def test_changes_frame_etag_changes_with_a_split_and_answers_304_when_unchanged(client, factory):
    seq = factory.ingested_sequence(n_frames=3, n_objects=2)
    op = factory.user()
    tid = factory.track_ids(seq)[0]
    fid = _frame_of(client, op, tid)
    etag = _get(client, op, f"/frames/{fid}/payload").headers["etag"]
    r = client.get(f"/api/v1/frames/{fid}/payload", headers={**op.headers, "If-None-Match": etag})
    assert r.status_code == 304 and r.content == b""
    _post(client, op, f"/tracks/{tid}/split", {"version": 1, "region": HALF})
    r = client.get(f"/api/v1/frames/{fid}/payload", headers={**op.headers, "If-None-Match": etag})
    assert r.status_code == 200 and r.headers["etag"] != etag


def test_the_cursor_is_utc_with_its_offset_and_a_since_in_another_zone_means_the_same_moment(client, factory):
    from datetime import datetime, timedelta, timezone

    seq = factory.ingested_sequence(n_frames=3, n_objects=2)
    op = factory.user()
    tid = factory.track_ids(seq)[0]
    cursor = _get(client, op, f"/sequences/{seq}/changes").json()["cursor"]
    moment = datetime.fromisoformat(cursor.replace("Z", "+00:00"))
    assert moment.utcoffset() == timedelta(0)  # RFC 3339 date-time: a naive one breaks the schema
    _post(client, op, f"/tracks/{tid}/split", {"version": 1, "region": HALF})
    east = moment.astimezone(timezone(timedelta(hours=2))).isoformat()
    assert tid in {t["id"] for t in _get(client, op, f"/sequences/{seq}/changes", since=east).json()["tracks"]}
    later = (moment + timedelta(hours=1)).astimezone(timezone(timedelta(hours=2))).isoformat()
    assert _get(client, op, f"/sequences/{seq}/changes", since=later).json()["tracks"] == []


def test_changes_feed_lists_the_split_tracks_and_their_frames_new_etags(client, factory):
    seq = factory.ingested_sequence(n_frames=3, n_objects=2)
    op = factory.user()
    tid = factory.track_ids(seq)[0]
    cursor = _get(client, op, f"/sequences/{seq}/changes").json()["cursor"]
    fid = _frame_of(client, op, tid)
    old = _get(client, op, f"/frames/{fid}/payload").headers["etag"]
    out = _post(client, op, f"/tracks/{tid}/split", {"version": 1, "region": HALF})
    feed = _get(client, op, f"/sequences/{seq}/changes", since=cursor).json()
    tracks = {t["id"]: t for t in feed["tracks"]}
    assert tracks[tid]["version"] == 2 and tracks[tid]["n_points"] == out["track"]["n_points"]
    assert tracks[out["new_track"]["id"]]["n_points"] == out["new_track"]["n_points"]
    etags = {f["id"]: f["etag"] for f in feed["frames"]}
    assert etags[fid] != old and etags[fid] == _get(client, op, f"/frames/{fid}/payload").headers["etag"]


def test_changes_split_undo_split_gives_a_fresh_id_and_the_old_edit_is_refused(client, factory):
    seq = factory.ingested_sequence(n_frames=3, n_objects=2)
    op = factory.user()
    tid = factory.track_ids(seq)[0]
    first = _post(client, op, f"/tracks/{tid}/split", {"version": 1, "region": HALF})["new_track"]
    _post(client, op, f"/tracks/{tid}/undo", {"version": 2})
    second = _post(client, op, f"/tracks/{tid}/split", {"version": 3, "region": HALF})["new_track"]
    assert second["id"] != first["id"]
    r = client.post(f"/api/v1/tracks/{first['id']}/label", json={"version": first["version"], "label": "car"},
                    headers=op.headers)
    assert r.status_code in (404, 409), r.text


def test_points_progress_counts_the_labelled_tracks_points_by_source(client, factory):
    seq = factory.ingested_sequence(n_frames=3, n_objects=2)
    op = factory.user()
    tid, other = factory.track_ids(seq)[:2]
    before = _get(client, op, f"/sequences/{seq}/points-progress").json()
    assert before["points_labelled"] == 0 and before["points_pending"] == before["points_in_tracks"] > 0
    assert before["points"] >= before["points_in_tracks"]
    labelled = _post(client, op, f"/tracks/{tid}/label", {"version": 1, "label": "car"})
    _post(client, op, f"/tracks/{other}/discard", {"version": 1})
    after = _get(client, op, f"/sequences/{seq}/points-progress").json()
    assert after["points_labelled_per_source"] == {"review": labelled["n_points"]} == {"review": after["points_labelled"]}
    assert after["points_discarded"] > 0
    assert after["points_in_tracks"] == before["points_in_tracks"]


def test_changes_feed_lists_the_live_ground_regions_in_every_answer(client, factory):
    seq = factory.ingested_sequence(n_frames=2, n_objects=1)
    op = factory.user()
    start = _get(client, op, f"/sequences/{seq}/changes").json()
    assert start["region_ids"] == []
    square = {"class_name": "bush", "polygon": [[0, 0], [5, 0], [5, 5], [0, 5]]}
    first = _post(client, op, f"/sequences/{seq}/ground-regions", square)
    assert _get(client, op, f"/sequences/{seq}/changes", since=start["cursor"]).json()["region_ids"] == [first["id"]]
    second = _post(client, op, f"/sequences/{seq}/ground-regions", square)  # the same polygon again: a new region
    assert client.delete(f"/api/v1/ground-regions/{first['id']}", headers=op.headers).status_code == 200
    assert _get(client, op, f"/sequences/{seq}/changes").json()["region_ids"] == [second["id"]]
