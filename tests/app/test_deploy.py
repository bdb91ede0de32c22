"""docker-compose.yml and the Dockerfile, checked by reading them (no Docker engine here)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
import yaml

from app.core.config import Settings

REPO = Path(__file__).resolve().parents[2]
ENV_FIELDS = {f"TRACKLABEL_{name.upper()}" for name in Settings.model_fields}


def annotate_envvars() -> set[str]:
    """Environment variables `tracklabel annotate` reads (its options' envvars)."""
    import typer

    from app.cli import app

    cmd = typer.main.get_command(app).commands["annotate"]  # type: ignore[attr-defined]
    return {p.envvar for p in cmd.params if isinstance(p.envvar, str)}


@pytest.fixture(scope="module")
def compose() -> dict:
    return yaml.safe_load((REPO / "docker-compose.yml").read_text())


def test_deploy_compose_names_the_services(compose):
    assert {"api", "worker", "postgres", "annotator"} <= set(compose["services"])


def test_deploy_compose_api_and_worker_share_one_image(compose):
    api, worker = compose["services"]["api"], compose["services"]["worker"]
    assert api["image"] == worker["image"] and api["build"] == worker["build"] == "."


def test_deploy_compose_every_service_has_a_healthcheck(compose):
    assert all("healthcheck" in svc for svc in compose["services"].values())


def test_deploy_compose_env_vars_are_settings_fields(compose):
    names = {k for name, svc in compose["services"].items() if name != "annotator" for k in (svc.get("environment") or {})}
    ours = {n for n in names if n.startswith("TRACKLABEL_")}
    assert ours and ours <= ENV_FIELDS, ours - ENV_FIELDS


def test_deploy_compose_annotator_env_vars_are_annotate_options(compose):
    names = set(compose["services"]["annotator"].get("environment") or {})
    assert names and names <= annotate_envvars(), names - annotate_envvars()


def test_deploy_compose_annotator_reaches_the_api_over_http_only(compose):
    ann, api = compose["services"]["annotator"], compose["services"]["api"]
    assert ann["image"] == api["image"] and ann["build"] == api["build"] == "."
    cmd = ann["command"]
    assert cmd[:2] == ["tracklabel", "annotate"] and cmd[cmd.index("--api") + 1] == "http://api:8000"
    assert "volumes" not in ann and not any(k.endswith("DATABASE_URL") for k in ann.get("environment") or {})
    assert "8080:8080" in ann["ports"] and "--no-viewer" in api["command"]  # one viewer, the service's


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


def test_deploy_compose_commands_use_real_cli_options(compose):
    import typer

    from app.cli import app

    commands = typer.main.get_command(app).commands  # type: ignore[attr-defined]
    for name in ("api", "worker", "annotator"):
        cmd = compose["services"][name]["command"]
        assert cmd[0] == "tracklabel" and cmd[1] in commands, cmd
        known = {o for p in commands[cmd[1]].params for o in (*p.opts, *p.secondary_opts)}
        used = {a for a in cmd[2:] if a.startswith("--")}
        assert used <= known, (name, used - known)
