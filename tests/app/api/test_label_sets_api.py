"""A sequence carries its label set: registered with it (a preset, default paper, or a label set
given as data), shown by GET, /sequences/{id}/label-set and /exports/stats, and added to existing
sequences as paper by migration 0012 (0013 adds the column of a set given as data)."""

from __future__ import annotations

import numpy as np
import pytest
from sqlalchemy import create_engine, text

from app.core.migrate import upgrade
from pipeline.classes import SAMPLE_CLASSES
from pipeline.label_sets import preset


def _register(client, factory, settings, **body):
    folder = settings.data_roots[0] / "seq"
    (folder / "velodyne").mkdir(parents=True, exist_ok=True)
    np.zeros((4, 4), np.float32).tofile(folder / "velodyne" / "000000.bin")
    admin = factory.user("admin")
    return client.post("/api/v1/datasets", json={"path": str(folder), "ingest": False, **body}, headers=admin.headers), admin


def test_label_sets_api_sequence_is_paper_by_default_and_get_shows_it(client, factory, settings):
    r, admin = _register(client, factory, settings)
    assert r.status_code == 201, r.text
    seq = r.json()["sequences"][0]
    assert seq["label_set"] == "paper"
    got = client.get(f"/api/v1/sequences/{seq['id']}", headers=admin.headers).json()
    assert got["label_set"] == "paper"


def test_label_sets_api_explicit_paper_is_registered(client, factory, settings):
    r, _ = _register(client, factory, settings, label_set="paper")
    assert r.status_code == 201 and r.json()["sequences"][0]["label_set"] == "paper"


def test_label_sets_api_unknown_label_set_is_422_naming_the_presets(client, factory, settings):
    r, admin = _register(client, factory, settings, label_set="kitti360")
    assert r.status_code == 422
    assert "unknown label set 'kitti360'" in r.text and "semantickitti" in r.text
    assert client.get("/api/v1/sequences", headers=admin.headers).json() == []


@pytest.mark.parametrize("name", ["semantickitti", "nuscenes"])
def test_label_sets_api_every_preset_is_registered_and_its_classes_served(client, factory, settings, name):
    r, admin = _register(client, factory, settings, label_set=name)
    assert r.status_code == 201, r.text
    seq = r.json()["sequences"][0]
    assert seq["label_set"] == name
    got = client.get(f"/api/v1/sequences/{seq['id']}/label-set", headers=admin.headers).json()
    assert got["name"] == name and got["sample_classes"] == list(preset(name).sample_class_names)
    assert [c["name"] for c in got["classes"]] == list(preset(name).point_class_names)
    assert [c["index"] for c in got["classes"]] == list(range(len(got["classes"])))


def _campus() -> dict:
    return {"name": "campus", "classes": [
        {"name": "walker", "colour": [255, 0, 0], "key": "1", "reads": [30], "writes": 30, "kind": "thing"},
        {"name": "cart", "colour": [0, 0, 255], "key": "2", "reads": [10], "writes": 10, "kind": "thing"},
        {"name": "lawn", "colour": [0, 255, 0], "key": "3", "reads": [72], "writes": 72, "kind": "stuff", "ground": True},
    ]}


def test_label_sets_api_label_set_given_as_data_is_stored_with_the_sequence(client, factory, settings):
    r, admin = _register(client, factory, settings, label_set=_campus())
    assert r.status_code == 201, r.text
    seq = r.json()["sequences"][0]
    assert seq["label_set"] == "campus"
    got = client.get(f"/api/v1/sequences/{seq['id']}/label-set", headers=admin.headers).json()
    assert got["sample_classes"] == ["walker", "cart"] and got["ground_classes"] == ["lawn"]
    assert got["classes"][0] == {"index": 0, "name": "walker", "colour": [255, 0, 0], "key": "1", "reads": [30],
                                 "writes": 30, "moving": None, "kind": "thing", "ground": False}


def test_label_sets_api_invalid_label_set_data_is_422_naming_the_field(client, factory, settings):
    bad = _campus()
    bad["classes"][1]["colour"] = [0, 0, 256]
    r, admin = _register(client, factory, settings, label_set=bad)
    assert r.status_code == 422
    assert "label_set: field classes.1 (cart).colour.2" in r.json()["detail"][0]["msg"], r.text
    assert client.get("/api/v1/sequences", headers=admin.headers).json() == []


def test_label_sets_api_label_set_data_under_a_preset_name_is_422(client, factory, settings):
    r, _ = _register(client, factory, settings, label_set={**_campus(), "name": "paper"})
    assert r.status_code == 422 and "'paper' is a preset's name" in r.text


def test_label_sets_api_path_like_label_set_is_refused_by_the_schema(client, factory, settings):
    r, _ = _register(client, factory, settings, label_set="../paper.yaml")
    assert r.status_code == 422 and "label_set" in r.text


def test_label_sets_api_stats_name_the_sequence_label_set_and_classes(client, factory):
    seq = factory.ingested_sequence(n_frames=3, n_objects=2)
    op = factory.user()
    one = client.get("/api/v1/exports/stats", params={"sequence_id": seq}, headers=op.headers).json()
    assert one["label_set"] == "paper" and one["classes"] == list(SAMPLE_CLASSES)
    every = client.get("/api/v1/exports/stats", headers=op.headers).json()
    assert every["label_set"] is None and every["classes"] == []


def test_label_sets_api_migration_makes_existing_sequences_paper(tmp_path):
    url = f"sqlite:///{tmp_path / 'm.db'}"
    upgrade(url, "0011")
    engine = create_engine(url)
    with engine.begin() as conn:
        conn.execute(text("INSERT INTO datasets (id, name, path, created_at) VALUES (1, 'd', '/d', '2026-01-01')"))
        conn.execute(text("INSERT INTO sequences (id, dataset_id, name, path, format, status, n_frames, created_at) "
                          "VALUES (1, 1, 's', '/d', 'semantickitti', 'ready', 0, '2026-01-01')"))
    upgrade(url, "0012")
    with engine.connect() as conn:
        assert conn.execute(text("SELECT label_set FROM sequences")).scalar_one() == "paper"
    engine.dispose()


def test_label_sets_api_track_filters_take_the_classes_of_the_registered_sets(client, factory, settings):
    r, admin = _register(client, factory, settings, label_set=_campus())
    assert r.status_code == 201, r.text
    sid = r.json()["sequences"][0]["id"]
    for params in ({"label": "walker"}, {"predicted_class": "cart", "sequence_id": sid}):
        got = client.get("/api/v1/tracks", params=params, headers=admin.headers)
        assert got.status_code == 200 and got.json()["total"] == 0, got.text
    bad = client.get("/api/v1/tracks", params={"label": "car", "sequence_id": sid}, headers=admin.headers)
    assert bad.status_code == 422 and "label: unknown class 'car'; valid: cart, walker" in bad.text
    assert client.get("/api/v1/anchors", params={"proposed_class": "dragon"}, headers=admin.headers).status_code == 422
