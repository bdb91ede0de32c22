"""docker-compose.yml and the Dockerfile, checked by reading them (no Docker engine here)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
import yaml

from app.core.config import Settings

REPO = Path(__file__).resolve().parents[2]
ENV_FIELDS = {f"TRACKLABEL_{name.upper()}" for name in Settings.model_fields}


@pytest.fixture(scope="module")
def compose() -> dict:
    return yaml.safe_load((REPO / "docker-compose.yml").read_text())


def test_deploy_compose_names_the_services(compose):
    assert {"api", "worker", "postgres"} <= set(compose["services"])


def test_deploy_compose_api_and_worker_share_one_image(compose):
    api, worker = compose["services"]["api"], compose["services"]["worker"]
    assert api["image"] == worker["image"] and api["build"] == worker["build"] == "."


def test_deploy_compose_every_service_has_a_healthcheck(compose):
    assert all("healthcheck" in svc for svc in compose["services"].values())


def test_deploy_compose_env_vars_are_settings_fields(compose):
    names = {k for svc in compose["services"].values() for k in (svc.get("environment") or {})}
    ours = {n for n in names if n.startswith("TRACKLABEL_")}
    assert ours and ours <= ENV_FIELDS, ours - ENV_FIELDS


def test_deploy_compose_env_parses_into_settings(compose, monkeypatch):
    for key, value in compose["services"]["worker"]["environment"].items():
        monkeypatch.setenv(key, str(value))
    s = Settings()
    assert s.db_url.startswith("postgresql+psycopg://") and s.data_roots == [Path("/datasets")]
    assert s.worker_alive_file == Path("/tmp/worker.alive") and s.job_lease_seconds == 30.0


def test_deploy_compose_api_runs_without_embedded_worker(compose):
    api = compose["services"]["api"]
    assert "--no-worker" in api["command"] and api["environment"]["TRACKLABEL_EMBEDDED_WORKER"] == "false"


def test_deploy_dockerfile_env_vars_are_settings_fields():
    text = (REPO / "Dockerfile").read_text()
    names = set(re.findall(r"\bTRACKLABEL_[A-Z_]+", text))
    assert names and names <= ENV_FIELDS
    assert 'CMD ["tracklabel", "serve"' in text and "/api/v1/health" in text
