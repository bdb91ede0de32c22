"""Adding classes changes a label set file alone (issue 35): a set of 25 classes, written as YAML by
the test, runs ingest -> review -> train -> predict -> export through the service on a small
simulated sequence, and every step speaks its classes."""

from __future__ import annotations

import io
import tarfile

import numpy as np
import pytest
import yaml

from app.worker import Worker
from pipeline.label_sets import read_label_set
from tests.app.factories import ingest_through_api, simulated_campus

N_SAMPLE, N_GROUND = 22, 3
TRAIN = {"model_size": "tiny", "epochs": 2, "steps_per_epoch": 3, "batch_labelled": 4, "threads": 1, "val_fraction": 0.0}


def _label_set_file(path):
    """25 classes: 22 that are not ground (ids 100..121; the first ten with hotkeys), 3 ground."""
    classes = [{"name": f"class{i:02d}", "colour": [10 * i, 255 - 10 * i, 100], "reads": [100 + i], "writes": 100 + i,
                "kind": "thing" if i % 2 else "stuff", **({"key": str((i + 1) % 10)} if i < 10 else {})}
               for i in range(N_SAMPLE)]
    classes += [{"name": name, "colour": [80, 80, 80 + 40 * j], "reads": reads, "writes": reads[0], "kind": "stuff",
                 "ground": True} for j, (name, reads) in enumerate([("road", [40, 60]), ("sidewalk", [48]),
                                                                      ("terrain", [72])])]
    path.write_text(yaml.safe_dump({"name": "many", "description": "25 classes", "classes": classes}, sort_keys=False))
    return path


@pytest.fixture(scope="module")
def simulated(tmp_path_factory):
    return simulated_campus(tmp_path_factory, frames=4, seed=0)


def _run(client, settings, db, admin, job_type, params):
    r = client.post("/api/v1/jobs", json={"type": job_type, "params": params}, headers=admin.headers)
    assert r.status_code == 202, r.text
    assert Worker(settings, db=db).run_once()
    job = client.get(f"/api/v1/jobs/{r.json()['id']}", headers=admin.headers).json()
    assert job["status"] == "succeeded", job["error"]
    return job


def test_label_set_25_classes_ingest_review_train_predict_export(client, factory, settings, db, simulated, tmp_path):
    from pipeline.model import load_checkpoint

    label_set = read_label_set(_label_set_file(tmp_path / "many.yaml"))
    assert len(label_set.classes) == N_SAMPLE + N_GROUND
    data = yaml.safe_load((tmp_path / "many.yaml").read_text())
    seq, _job, admin = ingest_through_api(client, factory, settings, db, simulated, label_set=data)
    sid = seq["id"]
    assert seq["label_set"] == "many"
    served = client.get(f"/api/v1/sequences/{sid}/label-set", headers=admin.headers).json()
    assert served["sample_classes"] == [f"class{i:02d}" for i in range(N_SAMPLE)]

    # review: the largest tracks get classes from both ends of the set; a paper class is refused
    tracks = client.get("/api/v1/tracks", params={"sequence_id": sid, "sort": "-n_points", "limit": 12},
                        headers=admin.headers).json()["items"]
    assert len(tracks) >= 8
    given = {}
    for t, i in zip(tracks, [0, 21, 5, 13, 0, 21, 5, 13, 9, 17, 9, 17], strict=False):
        name = f"class{i:02d}"
        r = client.post(f"/api/v1/tracks/{t['id']}/label", json={"version": t["version"], "label": name},
                        headers=admin.headers)
        assert r.status_code == 200, r.text
        given[t["id"]] = name
    r = client.post(f"/api/v1/tracks/{tracks[-1]['id']}/label", json={"version": 2, "label": "car"}, headers=admin.headers)
    assert r.status_code == 422 and "label: unknown class 'car' in label set 'many'" in r.text
    stats = client.get("/api/v1/exports/stats", params={"sequence_id": sid}, headers=admin.headers).json()
    assert stats["label_set"] == "many" and len(stats["classes"]) == N_SAMPLE

    # train: the model's outputs are the set's 22 classes that are not ground
    trained = _run(client, settings, db, admin, "train", {"sequence_ids": [sid], **TRAIN})
    per_class = trained["result"]["metrics"]["data"]["labels_per_class"]
    assert list(per_class) == served["sample_classes"] and per_class["class21"] > 0 and per_class["class01"] == 0
    _, meta = load_checkpoint(trained["result"]["path"], "cpu")
    assert meta.label_set == "many" and meta.classes == label_set.sample_class_names
    assert meta.model_config.num_classes == N_SAMPLE

    # predict: every track with a sample gets one of the set's classes
    predicted = _run(client, settings, db, admin, "predict",
                     {"model_id": trained["result"]["model_id"], "sequence_id": sid})
    assert predicted["result"]["tracks_predicted"] > 0
    assert set(predicted["result"]["predicted_per_class"]) <= set(served["sample_classes"])

    # export: the set's SemanticKITTI ids; ground takes its first ground class (road, 40)
    r = client.get(f"/api/v1/exports/semantickitti/{sid}", params={"include_ground": True}, headers=admin.headers)
    assert r.status_code == 200, r.text
    tar = tarfile.open(fileobj=io.BytesIO(r.content))
    ids = np.concatenate([np.frombuffer(tar.extractfile(n).read(), np.uint32) & 0xFFFF
                          for n in tar.getnames() if n.endswith(".label")])
    written = {c.writes for c in label_set.classes} | {0}
    assert set(np.unique(ids).tolist()) <= written
    assert {100, 121, 105, 113, 40} <= set(np.unique(ids).tolist())
    assert 48 not in ids and 72 not in ids  # ground is one class until ground patches exist
