"""Ground regions (the top view's lasso): stored per sequence, checked against its label set, and
applied by the export to the ground points inside them in every frame; deleting one undoes it."""

from __future__ import annotations

import io
import tarfile

import numpy as np

from pipeline.classes import SEMANTICKITTI_WRITE_ID

EVERYWHERE = [[-1e5, -1e5], [1e5, -1e5], [1e5, 1e5], [-1e5, 1e5]]


def _labels(client, caller, seq, **params):
    r = client.get(f"/api/v1/exports/semantickitti/{seq}", params={"include_ground": True, **params}, headers=caller.headers)
    assert r.status_code == 200, r.text
    tar = tarfile.open(fileobj=io.BytesIO(r.content))
    return [np.frombuffer(tar.extractfile(n).read(), np.uint32) & 0xFFFF
            for n in sorted(tar.getnames()) if n.endswith(".label")]


def _region(client, caller, seq, class_name, polygon, status=200, heights=None, **more):
    body = {"class_name": class_name, "polygon": polygon, **more}
    if heights is not None:
        body["z_min"], body["z_max"] = heights
    r = client.post(f"/api/v1/sequences/{seq}/ground-regions", json=body, headers=caller.headers)
    assert r.status_code == status, r.text
    return r.json()


def test_ground_region_relabels_the_ground_of_every_frame_until_deleted(client, factory):
    seq = factory.ingested_sequence(n_frames=3, n_objects=2)
    op = factory.user()
    before = _labels(client, op, seq)
    ground_id = SEMANTICKITTI_WRITE_ID["ground"]
    is_ground = [f == ground_id for f in before]
    assert all(g.sum() >= 30 for g in is_ground)
    region = _region(client, op, seq, "bush", EVERYWHERE)
    assert region["class_name"] == "bush" and region["sequence_id"] == seq and len(region["polygon"]) == 4
    after = _labels(client, op, seq)
    for b, a, g in zip(before, after, is_ground, strict=True):
        assert set(a[g].tolist()) == {SEMANTICKITTI_WRITE_ID["bush"]}
        assert np.array_equal(a[~g], b[~g])  # points that are not ground keep their labels
    # a newer region is drawn over the older one; the list is oldest first
    newer = _region(client, op, seq, "building", EVERYWHERE)
    listed = client.get(f"/api/v1/sequences/{seq}/ground-regions", headers=op.headers).json()
    assert [r["id"] for r in listed] == [region["id"], newer["id"]]
    assert all(set(a[g].tolist()) == {SEMANTICKITTI_WRITE_ID["building"]} for a, g in zip(_labels(client, op, seq), is_ground, strict=True))
    for r in (newer, region):
        assert client.delete(f"/api/v1/ground-regions/{r['id']}", headers=op.headers).status_code == 200
    assert all(np.array_equal(a, b) for a, b in zip(_labels(client, op, seq), before, strict=True))
    assert client.delete(f"/api/v1/ground-regions/{region['id']}", headers=op.headers).status_code == 404
    assert client.get(f"/api/v1/sequences/{seq}/ground-regions", headers=op.headers).json() == []
    # two drawn and two undone: four label-changing operations
    stats = client.get("/api/v1/exports/stats", params={"sequence_id": seq}, headers=op.headers).json()
    assert stats["operations"] == 4


def test_a_lasso_of_an_object_class_reaches_points_that_are_not_ground_and_one_of_a_ground_class_does_not(client, factory):
    seq = factory.ingested_sequence(n_frames=2, n_objects=2)
    op = factory.user()
    far = {"region_radius": 5.0}  # the synthetic objects stand farther than the default 0.3 m from the ground points
    before = _labels(client, op, seq, **far)
    not_ground = [f != SEMANTICKITTI_WRITE_ID["ground"] for f in before]
    bush = _region(client, op, seq, "bush", EVERYWHERE)
    reached = [(a != b) & n for a, b, n in zip(_labels(client, op, seq, **far), before, not_ground, strict=True)]
    assert sum(r.sum() for r in reached) > 0
    assert all(set(a[r].tolist()) <= {SEMANTICKITTI_WRITE_ID["bush"]} for a, r in zip(_labels(client, op, seq, **far), reached, strict=True))
    assert all(np.array_equal(a[n], b[n]) for a, b, n in zip(_labels(client, op, seq, region_radius=0.0), before, not_ground, strict=True))
    client.delete(f"/api/v1/ground-regions/{bush['id']}", headers=op.headers)
    _region(client, op, seq, "ground", EVERYWHERE)
    assert all(np.array_equal(a[n], b[n]) for a, b, n in zip(_labels(client, op, seq, **far), before, not_ground, strict=True))


def test_ground_region_refuses_a_class_outside_the_label_set_and_a_flat_polygon(client, factory):
    seq = factory.ingested_sequence(n_frames=1, n_objects=1)
    op = factory.user()
    assert "sidewalk" in _region(client, op, seq, "sidewalk", EVERYWHERE, 422)["detail"][0]["msg"]
    assert "area" in _region(client, op, seq, "car", [[0, 0], [1, 1], [2, 2]], 422)["detail"][0]["msg"]
    _region(client, op, seq, "car", [[0, 0], [1, 0]], 422)  # fewer than three vertices
    _region(client, op, seq, "car", [[0, 0], [1, 0], [1, "nan"]], 422)
    _region(client, op, 9999, "car", EVERYWHERE, 404)
    assert "below" in _region(client, op, seq, "car", EVERYWHERE, 422, heights=[1.0, 1.0])["detail"][0]["msg"]
    _region(client, op, seq, "car", EVERYWHERE, 422, heights=[0.0, "inf"])
    r = client.post(f"/api/v1/sequences/{seq}/ground-regions", headers=op.headers,
                    json={"class_name": "car", "polygon": EVERYWHERE, "z_min": 0.0})
    assert r.status_code == 422 and "both" in r.text
    assert client.get(f"/api/v1/sequences/{seq}/ground-regions", headers=op.headers).json() == []


def _review_one_as_car(client, caller, seq) -> None:
    track = client.get("/api/v1/tracks", params={"sequence_id": seq}, headers=caller.headers).json()["items"][0]
    r = client.post(f"/api/v1/tracks/{track['id']}/label", json={"version": track["version"], "label": "car"},
                    headers=caller.headers)
    assert r.status_code == 200, r.text


def test_region_with_heights_labels_every_point_between_them_a_reviewed_track_s_too(client, factory):
    seq = factory.ingested_sequence(n_frames=2, n_objects=2)
    op = factory.user()
    _review_one_as_car(client, op, seq)
    before = _labels(client, op, seq)
    car = SEMANTICKITTI_WRITE_ID["car"]
    assert any((b == car).any() for b in before)
    region = _region(client, op, seq, "building", EVERYWHERE, heights=[-1e4, 1e4])
    assert (region["z_min"], region["z_max"]) == (-1e4, 1e4)
    assert all(set(a.tolist()) == {SEMANTICKITTI_WRITE_ID["building"]} for a in _labels(client, op, seq))
    # a prism that holds no point's height changes nothing; deleting the first one undoes it
    _region(client, op, seq, "bush", EVERYWHERE, heights=[1e3, 1e4])
    assert client.delete(f"/api/v1/ground-regions/{region['id']}", headers=op.headers).status_code == 200
    assert all(np.array_equal(a, b) for a, b in zip(_labels(client, op, seq), before, strict=True))
    listed = client.get(f"/api/v1/sequences/{seq}/ground-regions", headers=op.headers).json()
    assert [(r["z_min"], r["z_max"]) for r in listed] == [(1e3, 1e4)]


# a camera whose view sends every point to the centre of the screen, between its planes
EVERY_POINT_VIEW = [0.0] * 15 + [1.0]
CENTRE = [[-0.5, -0.5], [0.5, -0.5], [0.5, 0.5], [-0.5, 0.5]]


def _view_lasso(client, caller, seq, class_name, frame, view=EVERY_POINT_VIEW, status=200):
    return _region(client, caller, seq, class_name, CENTRE, status, frame_index=frame, clip_from_world=view)


def test_a_lasso_in_a_frame_s_view_labels_every_point_of_that_frame_inside_it_and_no_other_frame(client, factory):
    seq = factory.ingested_sequence(n_frames=3, n_objects=2)
    op = factory.user()
    _review_one_as_car(client, op, seq)
    before = _labels(client, op, seq)
    region = _view_lasso(client, op, seq, "building", 1)
    assert region["frame_index"] == 1 and region["clip_from_world"] == EVERY_POINT_VIEW
    after = _labels(client, op, seq)
    assert set(after[1].tolist()) == {SEMANTICKITTI_WRITE_ID["building"]}  # a reviewed car's points too
    assert np.array_equal(after[0], before[0]) and np.array_equal(after[2], before[2])
    # a camera that looks away from every point (w < 0) labels none; undoing the lasso restores the frame
    away = [0.0] * 15 + [-1.0]
    _view_lasso(client, op, seq, "bush", 2, view=away)
    assert np.array_equal(_labels(client, op, seq)[2], before[2])
    assert client.delete(f"/api/v1/ground-regions/{region['id']}", headers=op.headers).status_code == 200
    assert all(np.array_equal(a, b) for a, b in zip(_labels(client, op, seq), before, strict=True))
    # the same polygon on the top view of frame 1 alone: only that frame's ground points
    _region(client, op, seq, "bush", EVERYWHERE, frame_index=1)
    ground = SEMANTICKITTI_WRITE_ID["ground"]
    after = _labels(client, op, seq)
    assert set(after[1][before[1] == ground].tolist()) == {SEMANTICKITTI_WRITE_ID["bush"]}
    assert np.array_equal(after[0], before[0]) and np.array_equal(after[2], before[2])


def test_a_lasso_in_a_view_needs_a_frame_the_sequence_has_and_a_finite_matrix(client, factory):
    seq = factory.ingested_sequence(n_frames=2, n_objects=1)
    op = factory.user()
    assert "no frame 7" in _view_lasso(client, op, seq, "car", 7, status=422)["detail"][0]["msg"]
    r = client.post(f"/api/v1/sequences/{seq}/ground-regions", headers=op.headers,
                    json={"class_name": "car", "polygon": CENTRE, "clip_from_world": EVERY_POINT_VIEW})
    assert r.status_code == 422 and "frame_index" in r.text
    _view_lasso(client, op, seq, "car", 0, view=EVERY_POINT_VIEW[:15], status=422)
    _view_lasso(client, op, seq, "car", 0, view=[*EVERY_POINT_VIEW[:15], "nan"], status=422)
    _view_lasso(client, op, seq, "car", -1, status=422)
    assert client.get(f"/api/v1/sequences/{seq}/ground-regions", headers=op.headers).json() == []
