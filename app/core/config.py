"""The service's one validated config: `Settings`, read from `TRACKLABEL_*` environment variables.

Loaded once at the edge (CLI, `create_app`, worker) and passed down explicitly; nothing below
reads the environment. Defaults give an embedded SQLite database under `data_dir`.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Annotated

from pydantic import Field, field_validator, model_validator
from pydantic_settings import BaseSettings, NoDecode, SettingsConfigDict


def default_data_dir() -> Path:
    """One data folder per user, whatever folder a command runs from: `$XDG_DATA_HOME/tracklabel`,
    else `~/.local/share/tracklabel` (a `./data` default gave each working folder its own database)."""
    base = os.environ.get("XDG_DATA_HOME") or str(Path.home() / ".local" / "share")
    return Path(base) / "tracklabel"


class Settings(BaseSettings):
    """Service settings. Every field is read from `TRACKLABEL_<FIELD>` (case-insensitive)."""

    model_config = SettingsConfigDict(env_prefix="TRACKLABEL_", extra="ignore")

    data_dir: Path = Field(default_factory=default_data_dir)
    # SQLAlchemy URL; None = sqlite file `<data_dir>/tracklabel.db`.
    database_url: str | None = None
    # Per-frame artifact files (compressed .npz); None = `<data_dir>/artifacts`.
    artifact_dir: Path | None = None
    # Folders under which sequences may be registered (os.pathsep- or comma-separated in the env);
    # empty = `<data_dir>` only.
    data_roots: Annotated[list[Path], NoDecode] = Field(default_factory=list)
    # Optional YAML of pipeline overrides used by ingest jobs.
    pipeline_config: Path | None = None

    # Jobs and worker.
    job_lease_seconds: float = Field(default=30.0, gt=0)
    job_heartbeat_seconds: float = Field(default=5.0, gt=0)
    job_max_attempts: int = Field(default=3, ge=1)
    worker_poll_seconds: float = Field(default=1.0, gt=0)
    # Job policy (app/jobs/policy.py): per-user limits and per-type run-time overrides (seconds,
    # JSON in the env: '{"finetune": 600}').
    job_max_queued_per_user: int = Field(default=5, ge=1)
    job_max_running_per_user: int = Field(default=2, ge=1)
    job_max_run_seconds: dict[str, float] = Field(default_factory=dict)
    # Extra modules imported at start-up that register job types (plugins, tests).
    job_modules: Annotated[list[str], NoDecode] = Field(default_factory=list)
    ingest_batch_frames: int = Field(default=10, ge=1)
    # Touched on every worker poll and heartbeat (container healthchecks read its age).
    worker_alive_file: Path | None = None

    # Review queue: how long `next` reserves a track for its operator.
    review_lease_seconds: float = Field(default=300.0, gt=0)
    # The model in the review loop (app/jobs/assist.py): the worker classifies a sequence's tracks
    # when it becomes ready, then again after every `assist_every` review events; 0 = off.
    assist_every: int = Field(default=5, ge=0, le=100_000)

    # Viewer frame payloads kept in memory (LRU).
    frame_cache_mb: int = Field(default=256, ge=0)
    # Tokens: days a new token is valid unless its issuer says otherwise (`--expires-days`).
    token_expiry_days: float = Field(default=90.0, gt=0, le=36500)
    # Largest request body accepted (bytes); a longer one gets 413 without being read.
    max_body_bytes: int = Field(default=1 << 20, ge=1024)
    # Invalid tokens one client address may present per minute; then 429 until the minute
    # passes (per API process; app/api/security.py).
    auth_failures_per_minute: int = Field(default=20, ge=1, le=100_000)
    # Addresses whose X-Forwarded-For uvicorn trusts (the TLS proxy's), so that the limit above
    # counts per client and not per proxy; "*" trusts any (only where the API port is private).
    forwarded_allow_ips: str = "127.0.0.1"

    # HTTP server (`tracklabel serve`).
    host: str = "127.0.0.1"
    port: int = Field(default=8000, ge=0, le=65535)
    # one job worker thread inside the API process (create_app); off by default: `serve` starts
    # worker processes instead, so that no job shares the API's event loop and memory
    embedded_worker: bool = False
    threadpool_size: int = Field(default=8, ge=1, le=256)  # threads for the sync routes
    gil_switch_interval_ms: float = Field(default=1.0, gt=0, le=100)  # Python's default is 5 ms
    # GET requests computing their answers at once; writes never wait for these (app/api/read_limit.py)
    read_concurrency: int = Field(default=1, ge=1, le=256)

    @field_validator("data_roots", mode="before")
    @classmethod
    def _split_roots(cls, value: object) -> object:
        if isinstance(value, str):
            parts = [p for chunk in value.split(",") for p in chunk.split(os.pathsep)]
            return [p.strip() for p in parts if p.strip()]
        return value

    @field_validator("job_modules", mode="before")
    @classmethod
    def _split_modules(cls, value: object) -> object:
        if isinstance(value, str):
            return [p.strip() for p in value.split(",") if p.strip()]
        return value

    @model_validator(mode="after")
    def _fill_defaults(self) -> Settings:
        if self.database_url is None:
            self.database_url = f"sqlite:///{(self.data_dir / 'tracklabel.db').as_posix()}"
        if self.artifact_dir is None:
            self.artifact_dir = self.data_dir / "artifacts"
        if not self.data_roots:
            self.data_roots = [self.data_dir]
        return self

    @property
    def db_url(self) -> str:
        assert self.database_url is not None
        return self.database_url

    @property
    def artifacts_path(self) -> Path:
        assert self.artifact_dir is not None
        return self.artifact_dir

    @property
    def is_sqlite(self) -> bool:
        return self.db_url.startswith("sqlite")


def get_settings() -> Settings:
    """Settings from the environment (call at the edge only)."""
    return Settings()
