"""Ingest with the real perception pipeline on a small simulated sequence."""

from __future__ import annotations

import io

import numpy as np
import pytest

from app.worker import Worker
from tests.app.factories import ingest_through_api, simulated_campus


@pytest.fixture(scope="module")
def simulated(tmp_path_factory):
    return simulated_campus(tmp_path_factory, frames=4, seed=0)


def test_ingest_pipeline_simulated_sequence_end_to_end(client, factory, settings, db, simulated):
    seq, job, admin = ingest_through_api(client, factory, settings, db, simulated)
    assert job["result"]["frames"] == 4 and job["result"]["tracks"] > 0 and job["result"]["constraints"] > 0

    seq_pub = client.get(f"/api/v1/sequences/{seq['id']}", headers=admin.headers).json()
    assert seq_pub["status"] == "ready" and seq_pub["sensor"]["name"] == "hdl32e"
    frame = client.get(f"/api/v1/sequences/{seq['id']}/frames", headers=admin.headers).json()["items"][1]
    z = np.load(io.BytesIO(client.get(f"/api/v1/frames/{frame['id']}/payload", headers=admin.headers).content))
    n_bin = (simulated / "velodyne" / f"{frame['name']}.bin").stat().st_size // 16
    assert len(z["points"]) == frame["n_points"] <= n_bin and (z["track"] > 0).any()


def test_ingest_pipeline_corrupt_frame_0_and_empty_frame_are_skipped_and_reported(client, factory, settings, db, simulated, tmp_path):
    # defect 8: a corrupt frame 0 failed the whole ingest; a 0-byte .bin became a 0-point frame
    import shutil

    seq_dir = settings.data_roots[0] / "damaged"
    shutil.copytree(simulated, seq_dir)
    shutil.rmtree(seq_dir / "labels", ignore_errors=True)  # a scan to label, not a labelled one
    bins = sorted((seq_dir / "velodyne").glob("*.bin"))
    bins[0].write_bytes(b"\0" * 7)
    bins[2].write_bytes(b"")
    admin = factory.user("admin")
    r = client.post("/api/v1/datasets", json={"path": "damaged"}, headers=admin.headers)
    assert r.status_code == 201, r.text
    seq = r.json()["sequences"][0]
    assert Worker(settings, db=db).run_once()
    job = client.get(f"/api/v1/jobs/{seq['ingest_job_id']}", headers=admin.headers).json()
    assert job["status"] == "succeeded", job["error"]
    skipped = job["result"]["skipped"]
    assert job["result"]["frames"] == 2 and len(skipped) == 2
    assert skipped[0].startswith("frame 0") and skipped[1].startswith("frame 2") and "empty scan file" in skipped[1]
