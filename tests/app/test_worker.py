from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from datetime import timedelta
from pathlib import Path

from sqlalchemy import func, select, update

from app.models import Frame, Job, PairConstraint, Segment, Sequence, Track, utcnow
from app.worker import Worker
from tests.app.fakes import expected_counts, fake_frame, fake_pipeline

REPO = Path(__file__).resolve().parents[2]


def _queue_selftest(factory, db, **params):
    from app import crud

    with db.write() as s:
        job = crud.create_job(s, "selftest", params, None)
        s.commit()
        return job.id


def test_worker_claims_oldest_queued_job(factory, db, settings):
    first = _queue_selftest(factory, db)
    _queue_selftest(factory, db)
    claimed = Worker(settings, db=db).claim()
    assert claimed is not None and claimed.id == first and claimed.attempt == 1


def test_worker_two_workers_never_claim_the_same_job(factory, db, settings):
    _queue_selftest(factory, db)
    a, b = Worker(settings, db=db), Worker(settings, db=db)
    assert a.claim() is not None and b.claim() is None


def test_worker_concurrent_claims_never_share_a_job(factory, db, settings):
    import threading

    for _ in range(24):
        _queue_selftest(factory, db)
    claimed: list[int] = []
    lock = threading.Lock()

    def drain() -> None:
        w = Worker(settings, db=db)
        while (job := w.claim()) is not None:
            with lock:
                claimed.append(job.id)

    threads = [threading.Thread(target=drain) for _ in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert sorted(claimed) == sorted(set(claimed)) and len(claimed) == 24


def test_worker_reclaims_job_with_expired_lease(factory, db, settings):
    job_id = _queue_selftest(factory, db)
    Worker(settings, db=db).claim()
    with db.write() as s:
        s.execute(update(Job).where(Job.id == job_id).values(lease_expires_at=utcnow() - timedelta(seconds=1)))
        s.commit()
    again = Worker(settings, db=db).claim()
    assert again is not None and again.id == job_id and again.attempt == 2


def test_worker_fails_job_after_max_attempts(factory, db, settings):
    job_id = _queue_selftest(factory, db)
    with db.write() as s:
        s.execute(
            update(Job)
            .where(Job.id == job_id)
            .values(status="running", attempts=settings.job_max_attempts, lease_expires_at=utcnow() - timedelta(seconds=1))
        )
        s.commit()
    assert Worker(settings, db=db).claim() is None
    with db.read() as s:
        assert s.get(Job, job_id).status == "failed"


def test_worker_heartbeat_renews_lease(factory, db, settings):
    settings.job_lease_seconds = 0.5
    job_id = _queue_selftest(factory, db, steps=10, step_seconds=0.1)
    Worker(settings, db=db).run_once()  # 1 s of work with a 0.5 s lease: only heartbeats keep it
    with db.read() as s:
        job = s.get(Job, job_id)
    assert (job.status, job.attempts) == ("succeeded", 1)


def _row_counts(db, seq_id):
    with db.read() as s:
        dup_frames = s.scalar(
            select(func.count()).select_from(
                select(Frame.index).where(Frame.sequence_id == seq_id).group_by(Frame.index).having(func.count() > 1).subquery()
            )
        )
        return dup_frames, {
            "frames": s.scalar(select(func.count()).where(Frame.sequence_id == seq_id)),
            "segments": s.scalar(select(func.count()).where(Segment.sequence_id == seq_id)),
            "tracks": s.scalar(select(func.count()).where(Track.sequence_id == seq_id)),
            "constraints": s.scalar(select(func.count()).where(PairConstraint.sequence_id == seq_id)),
        }


def test_worker_sigkill_mid_job_is_completed_by_another_worker(factory, db, settings):
    seq = factory.registered_sequence()
    job_id = factory.queue_ingest(seq)
    env = {
        **os.environ,
        "TRACKLABEL_DATABASE_URL": settings.db_url,
        "TRACKLABEL_DATA_DIR": str(settings.data_dir),
        "TRACKLABEL_JOB_LEASE_SECONDS": "1.5",
        "TRACKLABEL_JOB_HEARTBEAT_SECONDS": "0.3",
        "TRACKLABEL_INGEST_BATCH_FRAMES": "3",
        "TRACKLABEL_JOB_MODULES": "tests.app.slow_ingest_plugin",
        "FAKE_INGEST_FRAMES": "12",
        "FAKE_INGEST_DELAY": "0.2",
        "PYTHONPATH": str(REPO),
    }
    proc = subprocess.Popen([sys.executable, "-m", "app.worker"], cwd=REPO, env=env)
    try:
        deadline = time.monotonic() + 60
        while _row_counts(db, seq)[1]["frames"] < 3:  # at least one batch committed
            assert proc.poll() is None and time.monotonic() < deadline
            time.sleep(0.05)
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(timeout=10)
    finally:
        if proc.poll() is None:
            proc.kill()
    with db.read() as s:
        assert s.get(Job, job_id).status == "running" and s.get(Sequence, seq).status == "ingesting"
        # what the killed worker left visible is whole batches: frames 0..k-1 (k a multiple of the
        # batch size), each with all its segments and its artifact file
        indices = s.scalars(select(Frame.index).where(Frame.sequence_id == seq).order_by(Frame.index)).all()
        per_frame = dict(
            s.execute(
                select(Frame.index, func.count(Segment.id))
                .outerjoin(Segment, Segment.frame_id == Frame.id)
                .where(Frame.sequence_id == seq)
                .group_by(Frame.index)
            ).all()
        )
        artifacts = s.scalars(select(Frame.artifact).where(Frame.sequence_id == seq)).all()
    assert indices == list(range(len(indices))) and len(indices) % 3 == 0
    assert per_frame == {i: len(fake_frame(i, 4).segments.n_points) for i in indices}
    assert all((settings.artifacts_path / rel).is_file() for rel in artifacts)

    settings.job_lease_seconds = 1.5
    with fake_pipeline(n_frames=12, n_objects=4):
        other = Worker(settings, db=db)
        deadline = time.monotonic() + 30
        while not other.run_once():  # nothing to claim until the dead worker's lease expires
            assert time.monotonic() < deadline
            time.sleep(0.1)
    with db.read() as s:
        job = s.get(Job, job_id)
        assert (job.status, job.attempts, job.worker_id) == ("succeeded", 2, other.worker_id)
        assert s.get(Sequence, seq).status == "ready"
    dup, counts = _row_counts(db, seq)
    assert dup == 0 and counts == expected_counts(12, 4)
