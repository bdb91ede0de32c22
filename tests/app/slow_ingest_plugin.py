"""Job plugin for the worker-crash test (TRACKLABEL_JOB_MODULES): a slow fake pipeline."""

from __future__ import annotations

import os

from tests.app.fakes import FakePipeline

FakePipeline(
    n_frames=int(os.environ.get("FAKE_INGEST_FRAMES", "12")),
    n_objects=int(os.environ.get("FAKE_INGEST_OBJECTS", "4")),
    delay_s=float(os.environ.get("FAKE_INGEST_DELAY", "0.2")),
).install()
