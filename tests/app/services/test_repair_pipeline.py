"""Track split with the real pipeline on a small simulated sequence: the cut segments' samples
are rendered again exactly as ingest renders samples."""

from __future__ import annotations

import numpy as np
import pytest
from sqlalchemy import select

from app.models import Frame, Segment, Sequence, Track
from tests.app.factories import ingest_through_api, simulated_campus


@pytest.fixture(scope="module")
def simulated(tmp_path_factory):
    return simulated_campus(tmp_path_factory, frames=3, seed=1)


def _ingest(client, factory, settings, db, simulated):
    return ingest_through_api(client, factory, settings, db, simulated)[0]["id"]


def test_repair_pipeline_resample_reproduces_ingest_samples(client, factory, settings, db, simulated):
    """Re-rendering an unchanged frame's segments gives the samples ingest stored (the range
    image and ground rebuilt from the stored points match those of ingest)."""
    from pipeline.config import PipelineConfig
    from pipeline.resample import resample_segments
    from pipeline.sensors import SensorModel

    seq = _ingest(client, factory, settings, db, simulated)
    with db.read() as s:
        rel = s.scalars(select(Frame.artifact).where(Frame.sequence_id == seq).order_by(Frame.index)).first()
        sensor = s.get(Sequence, seq).sensor
    z = np.load(settings.data_dir / "artifacts" / rel)
    res = resample_segments(z["points"], z["intensity"], z["segment"], z["sample_segment"], SensorModel.from_dict(sensor),
                            PipelineConfig())
    assert res.table.valid.all()
    same = np.array([np.array_equal(res.samples[k], z["samples"][k]) for k in range(len(z["samples"]))])
    assert same.all(), f"{int((~same).sum())} of {len(same)} samples differ"


def test_repair_pipeline_split_renders_both_parts(client, factory, settings, db, simulated):
    seq = _ingest(client, factory, settings, db, simulated)
    op = factory.user()
    with db.read() as s:
        track = s.scalars(select(Track).where(Track.sequence_id == seq).order_by(Track.n_points.desc())).first()
        wx = s.scalars(select(Segment.wx).where(Segment.track_id == track.id)).all()
    region = {"kind": "halfspace", "normal": [1.0, 0.0, 0.0], "offset": float(np.mean(wx))}
    r = client.post(f"/api/v1/tracks/{track.id}/split", json={"version": track.version, "region": region}, headers=op.headers)
    assert r.status_code == 200, r.text
    new = r.json()["new_track"]
    with db.read() as s:
        segs = s.scalars(select(Segment).where(Segment.track_id.in_([track.id, new["id"]]))).all()
        frames = {f.id: f for f in s.scalars(select(Frame).where(Frame.sequence_id == seq)).all()}
    assert {s.track_id for s in segs} == {track.id, new["id"]}
    for seg in segs:
        z = np.load(settings.data_dir / "artifacts" / frames[seg.frame_id].artifact)
        mine = z["segment"] == seg.local_id
        assert int(mine.sum()) == seg.n_points and set(z["track"][mine].tolist()) == {seg.track_id}
        pose = np.asarray(frames[seg.frame_id].pose).reshape(4, 4)
        x_world = z["points"][mine].astype(np.float64) @ pose[0, :3] + pose[0, 3]
        assert (x_world >= region["offset"]).all() if seg.track_id == new["id"] else (x_world < region["offset"]).all()
        if seg.sample_index is not None:
            sample = z["samples"][seg.sample_index]
            assert z["sample_segment"][seg.sample_index] == seg.local_id and (sample[3] == 255).any()
        assert seg.valid == (seg.sample_index is not None)
