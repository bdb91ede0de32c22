"""Background jobs: a registry of job types and their handlers; `app.worker` runs them."""

from __future__ import annotations

from app.jobs.registry import JobType, get_job_type, job_types, load_job_types, register

__all__ = ["JobType", "get_job_type", "job_types", "load_job_types", "register"]
