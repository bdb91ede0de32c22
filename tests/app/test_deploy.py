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


def _env_file(name: str) -> dict[str, str]:
    """KEY=VALUE lines of a committed example env file."""
    lines = (REPO / f"{name}.example").read_text().splitlines()
    return dict(line.split("=", 1) for line in lines if line.strip() and not line.startswith("#"))


def test_deploy_compose_names_the_services(compose):
    assert {"api", "worker", "postgres", "annotator", "proxy"} <= set(compose["services"])


def test_deploy_compose_api_and_worker_share_one_image(compose):
    api, worker = compose["services"]["api"], compose["services"]["worker"]
    assert api["image"] == worker["image"] and api["build"] == worker["build"] == "."


def test_deploy_compose_credentials_come_from_env_files_not_defaults(compose):
    pg, api = compose["services"]["postgres"], compose["services"]["api"]
    assert "POSTGRES_PASSWORD" not in (pg.get("environment") or {}) and pg["env_file"] == "deploy/postgres.env"
    assert api["env_file"] == "deploy/tracklabel.env" and "tracklabel:tracklabel@" not in yaml.safe_dump(compose)
    ignored = (REPO / ".gitignore").read_text().splitlines()
    assert {"deploy/postgres.env", "deploy/tracklabel.env"} <= set(ignored)  # the real files never get committed
    password = _env_file("deploy/postgres.env")["POSTGRES_PASSWORD"]
    assert f":{password}@postgres" in _env_file("deploy/tracklabel.env")["TRACKLABEL_DATABASE_URL"]


def test_deploy_compose_only_the_tls_proxy_is_published(compose):
    published = {name for name, svc in compose["services"].items() if svc.get("ports")}
    assert published == {"proxy"} and "443:443" in compose["services"]["proxy"]["ports"]
    caddy = (REPO / "deploy" / "Caddyfile").read_text()
    assert "reverse_proxy api:8000" in caddy and "reverse_proxy annotator:8080" in caddy


def test_deploy_compose_annotator_requires_sign_in(compose):
    ann = compose["services"]["annotator"]
    assert "TRACKLABEL_TOKEN" not in (ann.get("environment") or {}) and "--token" not in ann["command"]
    assert "--insecure-single-user" not in ann["command"]


def test_deploy_annotate_token_on_a_shared_address_needs_the_flag():
    from typer.testing import CliRunner

    from app.cli import app

    r = CliRunner().invoke(app, ["annotate", "--token", "tl_x", "--host", "0.0.0.0", "--wait", "0"])
    assert r.exit_code == 2 and "--insecure-single-user" in r.output


def test_deploy_compose_every_service_has_a_healthcheck(compose):
    assert all("healthcheck" in svc for svc in compose["services"].values())


def test_deploy_compose_env_vars_are_settings_fields(compose):
    names = {k for name, svc in compose["services"].items() if name != "annotator" for k in (svc.get("environment") or {})}
    ours = {n for n in names if n.startswith("TRACKLABEL_")}
    assert ours and ours <= ENV_FIELDS, ours - ENV_FIELDS


def test_deploy_compose_annotator_env_vars_are_annotate_options(compose):
    names = set(compose["services"]["annotator"].get("environment") or {})
    assert names <= annotate_envvars(), names - annotate_envvars()


def test_deploy_compose_annotator_reaches_the_api_over_http_only(compose):
    ann, api = compose["services"]["annotator"], compose["services"]["api"]
    assert ann["image"] == api["image"] and ann["build"] == api["build"] == "."
    cmd = ann["command"]
    assert cmd[:2] == ["tracklabel", "annotate"] and cmd[cmd.index("--api") + 1] == "http://api:8000"
    assert "volumes" not in ann and "env_file" not in ann
    assert not any(k.endswith("DATABASE_URL") for k in ann.get("environment") or {})
    assert "8080" in ann["expose"] and "--no-viewer" in api["command"]  # one viewer, the service's


def test_deploy_compose_env_parses_into_settings(compose, monkeypatch):
    env = {**_env_file("deploy/tracklabel.env"), **compose["services"]["worker"]["environment"]}
    for key, value in env.items():
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
