"""Ingest opens a sequence as `tracklabel process` does (pipeline.sequence): the same range image,
the same tracks, poses from the file or estimated (`poses: "icp"`), and per-point exports with one
label per input point."""

from __future__ import annotations

import io
import json
import shutil
import tarfile
from pathlib import Path

import numpy as np
import pytest
from sqlalchemy import select

from app.artifacts import ArtifactStore
from app.models import Frame, Segment, Sequence, Track
from app.worker import Worker
from pipeline.io.semantickitti import read_bin
from pipeline.pipeline import run_process
from tests.app.factories import simulated_campus

KITTI_FRAMES = 4


@pytest.fixture(scope="module")
def kitti_seq00(real_data: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Frames 0-3 of SemanticKITTI sequence 00 with their poses, copied into a temporary folder."""
    src = real_data / "kitti_seq00"
    dest = tmp_path_factory.mktemp("kitti") / "seq00"
    (dest / "velodyne").mkdir(parents=True)
    for i in range(KITTI_FRAMES):
        shutil.copy(src / "velodyne" / f"{i:06d}.bin", dest / "velodyne")
    for name in ("poses.txt", "times.txt"):
        lines = (src / name).read_text().splitlines()[:KITTI_FRAMES]
        (dest / name).write_text("\n".join(lines) + "\n")
    shutil.copy(src / "calib.txt", dest)
    return dest


@pytest.fixture(scope="module")
def campus_with_bad_rows(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Three simulated frames without labels; frame 1 has 40 NaN rows and 5 points at 1e9 m."""
    seq = simulated_campus(tmp_path_factory, frames=3, seed=2)
    shutil.rmtree(seq / "labels")
    f = seq / "velodyne" / "000001.bin"
    raw = read_bin(f).copy()
    raw[100:140, 1] = np.nan
    raw[200:205, :3] = 1e9
    raw.tofile(f)
    return seq


def _ingest(client, factory, settings, db, path: Path, **body) -> int:
    settings.data_roots.append(path.parent)
    admin = factory.user("admin")
    r = client.post("/api/v1/datasets", json={"path": str(path), **body}, headers=admin.headers)
    assert r.status_code == 201, r.text
    assert Worker(settings, db=db).run_once()
    seq_id = r.json()["sequences"][0]["id"]
    with db.read() as s:
        seq = s.get(Sequence, seq_id)
        assert seq is not None and seq.status == "ready", factory.last_job_error()
    return seq_id


def _point_keys(db, settings, seq_id: int) -> dict[str, np.ndarray]:
    """Per frame name: the pipeline track id (Track.key) of every stored point, 0 = none."""
    store = ArtifactStore(settings.artifacts_path)
    with db.read() as s:
        key_of = dict(s.execute(select(Track.id, Track.key).where(Track.sequence_id == seq_id)).all())
        frames = s.execute(select(Frame.name, Frame.artifact).where(Frame.sequence_id == seq_id)).all()
    lut = {0: 0, **key_of}
    out = {}
    for name, artifact in frames:
        a = store.read_arrays(artifact, ("track", "input_rows"))
        keys = np.array([lut[int(t)] for t in a["track"]], np.int64)
        rows = a.get("input_rows")
        if rows is not None:
            full = np.zeros(len(rows), np.int64)
            full[rows] = keys
            keys = full
        out[name] = keys
    return out


@pytest.mark.real_data
def test_ingest_sequence_real_kitti_gives_the_tracks_of_process(client, factory, settings, db, kitti_seq00, tmp_path):
    out = tmp_path / "process"
    summary = run_process(kitti_seq00, out)
    seq_id = _ingest(client, factory, settings, db, kitti_seq00)
    stored = _point_keys(db, settings, seq_id)
    assert sorted(stored) == [f"{i:06d}" for i in range(KITTI_FRAMES)]
    for name, keys in stored.items():  # the same track of every point
        np.testing.assert_array_equal(keys, np.fromfile(out / "tracks" / f"{name}.label", np.uint32))
    tracks = json.loads((out / "tracks.json").read_text())["tracks"]
    with db.read() as s:
        rows = s.execute(
            select(Track.key, Segment.frame_index, Segment.n_points)
            .join(Segment, Segment.track_id == Track.id)
            .where(Track.sequence_id == seq_id)
        ).all()
        n_segments = sum(s.scalars(select(Frame.n_segments).where(Frame.sequence_id == seq_id)).all())
    segments = {(int(k), int(f)): int(n) for k, f, n in rows}
    expected = {(t["id"], f): n for t in tracks for f, n in zip(t["frames"], t["points"], strict=True)}
    assert segments == expected  # the same segments in the same tracks
    assert n_segments == summary["segments"] and len(tracks) == summary["tracks"] > 100


@pytest.mark.real_data
@pytest.mark.parametrize("sensor", ["auto", "hdl32e"])
def test_ingest_sequence_nuscenes_sweep_gets_the_range_image_of_process(
    client, factory, settings, db, real_data, tmp_path, sensor
):
    """The 20 Hz sweep has ~1,085 points per beam: both fit the width (2160 for the preset would
    leave every other column empty)."""
    sweep = tmp_path / "nuscenes"
    shutil.copytree(real_data / "nuscenes_hdl32e", sweep)
    summary = run_process(sweep, tmp_path / "process", sensor=sensor)
    seq_id = _ingest(client, factory, settings, db, sweep, config={"sensor": {"name": sensor}})
    with db.read() as s:
        stored = s.get(Sequence, seq_id).sensor
    assert [len(stored["elevations_deg"]), stored["width"]] == summary["range_image"]
    assert 1070 <= summary["range_image"][1] < 1100


def test_ingest_sequence_poses_icp_links_frames_without_poses(client, factory, settings, db, tmp_path_factory):
    seq = simulated_campus(tmp_path_factory, frames=3, seed=4)
    for name in ("poses.txt", "calib.txt"):
        (seq / name).unlink()
    seq_id = _ingest(client, factory, settings, db, seq, poses="icp")
    with db.read() as s:
        poses = s.scalars(select(Frame.pose).where(Frame.sequence_id == seq_id).order_by(Frame.index)).all()
        linked = s.scalars(select(Track.length).where(Track.sequence_id == seq_id, Track.length > 1)).all()
    assert all(p is not None for p in poses) and np.allclose(np.reshape(poses[0], (4, 4)), np.eye(4))
    assert np.linalg.norm(np.reshape(poses[2], (4, 4))[:3, 3]) > 0.2  # the car drove on
    assert linked  # estimated poses link tracks across frames


def test_ingest_sequence_unknown_poses_value_is_422(client, factory):
    seq_id = factory.registered_sequence()
    admin = factory.user("admin")
    r = client.post("/api/v1/jobs", json={"type": "ingest", "params": {"sequence_id": seq_id, "poses": "gps"}},
                    headers=admin.headers)
    assert r.status_code == 422 and "poses" in r.text
    r = client.post(f"/api/v1/sequences/{seq_id}/ingest", json={"poses": "gps"}, headers=admin.headers)
    assert r.status_code == 422


def test_ingest_sequence_export_has_one_label_per_input_row(client, factory, settings, db, campus_with_bad_rows):
    seq_id = _ingest(client, factory, settings, db, campus_with_bad_rows)
    op = factory.user()
    track = factory.track_ids(seq_id)[0]
    r = client.post(f"/api/v1/tracks/{track}/label", json={"version": 1, "label": "car"}, headers=op.headers)
    assert r.status_code == 200, r.text
    r = client.get(f"/api/v1/exports/semantickitti/{seq_id}", headers=op.headers)
    tar = tarfile.open(fileobj=io.BytesIO(r.content))
    for name in ("000000", "000001", "000002"):
        raw = read_bin(campus_with_bad_rows / "velodyne" / f"{name}.bin")
        member = tar.extractfile(f"sequences/campus/labels/{name}.label")
        assert member is not None
        label = np.frombuffer(member.read(), np.uint32)
        assert len(label) == len(raw), name
        assert not label[~np.isfinite(raw).all(axis=1)].any()
