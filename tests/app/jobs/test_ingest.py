from __future__ import annotations

import contextlib

import pytest
from sqlalchemy import func, select

from app.models import Frame, Job, PairConstraint, Segment, Sequence, Track
from app.worker import Worker
from tests.app.fakes import FakePipeline, expected_counts, fake_pipeline


@pytest.fixture
def backend():
    with contextlib.ExitStack() as stack:
        yield lambda **kw: stack.enter_context(fake_pipeline(**kw))


def _counts(db, seq_id):
    with db.read() as s:
        return {
            "frames": s.scalar(select(func.count()).where(Frame.sequence_id == seq_id)),
            "segments": s.scalar(select(func.count()).where(Segment.sequence_id == seq_id)),
            "tracks": s.scalar(select(func.count()).where(Track.sequence_id == seq_id)),
            "constraints": s.scalar(select(func.count()).where(PairConstraint.sequence_id == seq_id)),
        }


def test_ingest_writes_frames_segments_tracks_constraints(factory, db):
    seq = factory.ingested_sequence(n_frames=7, n_objects=5)
    assert _counts(db, seq) == expected_counts(7, 5)


def test_ingest_track_ranges_and_samples(factory, db):
    factory.ingested_sequence(n_frames=6, n_objects=3)
    with db.read() as s:
        rows = s.execute(
            select(Track.key, Track.first_frame, Track.last_frame, Track.length, Track.n_samples).order_by(Track.key)
        ).all()
    assert [tuple(r) for r in rows] == [(1, 0, 5, 6, 6), (2, 1, 5, 5, 5), (3, 2, 5, 4, 4)]


def test_ingest_failure_marks_sequence_failed_with_whole_batches(factory, db, settings, backend):
    seq = factory.registered_sequence()
    factory.queue_ingest(seq)
    backend(n_frames=8, fail_at=5)  # batches of 3: frames 0-2 commit, 3-4 never do
    Worker(settings, db=db).run_once()
    with db.read() as s:
        assert s.get(Sequence, seq).status == "failed"
        assert s.scalars(select(Job.status)).one() == "failed"
        frames = s.scalars(select(Frame.index).where(Frame.sequence_id == seq).order_by(Frame.index)).all()
        orphans = s.scalar(select(func.count()).select_from(Frame).where(~Frame.id.in_(select(Segment.frame_id))))
    assert frames == [0, 1, 2] and orphans == 0


def test_ingest_retry_rolls_back_and_completes_without_duplicates(factory, db, settings, backend):
    seq = factory.registered_sequence()
    factory.queue_ingest(seq)
    backend(n_frames=8, n_objects=4, fail_at=5)
    Worker(settings, db=db).run_once()
    factory.queue_ingest(seq)
    backend(n_frames=8, n_objects=4)
    Worker(settings, db=db).run_once()
    assert _counts(db, seq) == expected_counts(8, 4)


def test_ingest_ready_sequence_needs_force(client, factory):
    admin = factory.user("admin")
    seq = factory.ingested_sequence()
    r = client.post(f"/api/v1/sequences/{seq}/ingest", json={}, headers=admin.headers)
    assert r.status_code == 409
    r = client.post(f"/api/v1/sequences/{seq}/ingest", json={"force": True}, headers=admin.headers)
    assert r.status_code == 202


def test_ingest_artifacts_hold_db_track_ids(factory, db, settings):
    from app.artifacts import ArtifactStore

    seq = factory.ingested_sequence(n_frames=2, n_objects=2)
    with db.read() as s:
        art = s.scalar(select(Frame.artifact).where(Frame.sequence_id == seq, Frame.index == 1))
        tracks = set(s.scalars(select(Track.id).where(Track.sequence_id == seq)).all())
    fa = ArtifactStore(settings.artifacts_path).read_frame(art)
    assert set(fa.track[fa.track > 0].tolist()) == tracks


class _NoSegmentsProcessor:
    """Frames whose points are all ground: no segment, no track."""

    linked = True

    def iter_frames(self, source, **_):
        import numpy as np

        from tests.app.fakes import SAMPLE_SHAPE, fake_frame

        for i in range(len(source)):
            fr = fake_frame(i, n_objects=1)
            fr.samples, fr.sample_segment = np.zeros((0, *SAMPLE_SHAPE), np.uint8), np.zeros(0, np.int32)
            fr.segment = np.full(len(fr.segment), -1, np.int32)
            fr.ground = np.ones(len(fr.segment), bool)
            for name in ("n_points", "range", "valid", "track_id", "link_score"):
                setattr(fr.segments, name, getattr(fr.segments, name)[:0])
            fr.segments.centroid = fr.segments.centroid_world = np.zeros((0, 3))
            yield fr


class _NoSegmentsPipeline(FakePipeline):
    def processor(self, config, sensor):
        return _NoSegmentsProcessor()


def test_ingest_frames_without_segments_ingest_as_empty(factory, db):
    """A scan with no segment used to fail the ingest (IndexError indexing an empty track table)."""
    seq = factory.registered_sequence()
    factory.queue_ingest(seq)
    with fake_pipeline(_NoSegmentsPipeline(n_frames=2)):
        assert Worker(factory.settings, db=db).run_once()
    with db.read() as s:
        assert s.get(Sequence, seq).status == "ready", factory.last_job_error()
    assert _counts(db, seq) == {"frames": 2, "segments": 0, "tracks": 0, "constraints": 0}
