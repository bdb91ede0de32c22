"""Job plugin for the worker-crash test (TRACKLABEL_JOB_MODULES): a slow fake ingest backend."""

from __future__ import annotations

import os

from app.jobs import ingest
from tests.app.fakes import FakeBackend

ingest.set_backend(
    FakeBackend(
        n_frames=int(os.environ.get("FAKE_INGEST_FRAMES", "12")),
        n_objects=int(os.environ.get("FAKE_INGEST_OBJECTS", "4")),
        delay_s=float(os.environ.get("FAKE_INGEST_DELAY", "0.2")),
    )
)
