from __future__ import annotations

from datetime import timedelta

from app import crud
from app.crud.jobs import ClaimRules, claim_job, finish_job_values, job_owner, update_running_job
from app.models import Job, utcnow


def _queue(db, job_type="selftest", user_id=None, **params):
    with db.write() as s:
        job = crud.create_job(s, job_type, params, user_id)
        s.commit()
        return job.id


def _rules(max_running=10, max_attempts=3):
    return ClaimRules(["selftest"], max_running, max_attempts, timedelta(seconds=30))


def test_jobs_claim_skips_types_the_worker_does_not_know(db):
    _queue(db, "ingest", sequence_id=1)
    with db.write() as s:
        assert claim_job(s, _rules(), "w1") is None


def test_jobs_claim_leaves_jobs_of_users_at_the_running_limit_waiting(db, factory):
    op = factory.user("operator")
    first, second = _queue(db, user_id=op.id), _queue(db, user_id=op.id)
    with db.write() as s:
        assert claim_job(s, _rules(max_running=1), "w1").id == first
        assert claim_job(s, _rules(max_running=1), "w2") is None
        assert claim_job(s, _rules(max_running=2), "w2").id == second


def test_jobs_claim_fails_an_expired_job_out_of_attempts(db):
    job_id = _queue(db)
    with db.write() as s:
        claim_job(s, _rules(max_attempts=1), "w1")
        s.get(Job, job_id).lease_expires_at = utcnow() - timedelta(seconds=60)
        s.commit()
        assert claim_job(s, _rules(max_attempts=1), "w2") is None
    with db.read() as s:
        job = s.get(Job, job_id)
        assert job.status == "failed" and job.error == "lease expired after 1 attempts"


def test_jobs_update_running_job_reports_a_lost_lease_and_a_cancel(db):
    job_id = _queue(db)
    with db.write() as s:
        claim_job(s, _rules(), "w1")
        assert update_running_job(s, job_id, "w2", {"progress": 0.5}).owned is False
        crud.cancel_job(s, job_id)
        running = update_running_job(s, job_id, "w1", {"progress": 0.5})
    assert running.owned and running.cancel_requested
    with db.read() as s:
        assert s.get(Job, job_id).progress == 0.5


def test_jobs_finish_values_never_end_a_job_before_it_started(db):
    job_id = _queue(db)
    with db.write() as s:
        claim_job(s, _rules(), "w1")
        job = s.get(Job, job_id)
        job.started_at = job.started_at + timedelta(hours=1)  # stamped by a machine whose clock is ahead
        s.commit()
        update_running_job(s, job_id, "w1", finish_job_values("failed", None, "boom", ""))
    with db.read() as s:
        job = s.get(Job, job_id)
        assert job.status == "failed" and job.message == "failed" and job.error == "boom"
        assert job.finished_at == job.started_at


def test_jobs_queued_count_and_owner_are_per_user(db, factory):
    a, b = factory.user("operator"), factory.user("operator")
    job_id = _queue(db, user_id=a.id)
    _queue(db, user_id=a.id)
    with db.read() as s:
        assert crud.queued_count(s, a.id) == 2 and crud.queued_count(s, b.id) == 0
        assert job_owner(s, job_id) == a.id and job_owner(s, 10_000) is None


def test_jobs_job_runs_lists_status_and_params_of_one_type(db):
    _queue(db, "assist", sequence_id=3, after_event=7)
    _queue(db, sequence_id=4)
    with db.read() as s:
        assert crud.job_runs(s, "assist") == [("queued", {"sequence_id": 3, "after_event": 7})]
