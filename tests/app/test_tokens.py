"""Tokens and users (issue 23, defect 13): revoke (by user or prefix), disable, expiry; over the
CLI and the admin API; refused from the very next request (no cache window)."""

from __future__ import annotations

from datetime import timedelta

import pytest
from typer.testing import CliRunner

from app.cli import app as cli
from app.main import create_app
from app.models import ApiToken, utcnow

ME = "/api/v1/users/me"


def test_tokens_revoked_token_is_refused_on_the_next_request(client, factory):
    admin, op = factory.user("admin"), factory.user("operator")
    assert client.get(ME, headers=op.headers).status_code == 200
    assert client.post(f"/api/v1/users/{op.id}/revoke", headers=admin.headers).json() == {"revoked": 1}
    r = client.get(ME, headers=op.headers)
    assert r.status_code == 401 and "revoked" in r.json()["detail"]


def test_tokens_revoke_by_prefix_leaves_other_tokens(client, factory):
    admin, op = factory.user("admin"), factory.user("operator")
    second = client.post(f"/api/v1/users/{op.id}/tokens", json={}, headers=admin.headers).json()["token"]
    r = client.post("/api/v1/tokens/revoke", json={"prefix": op.token[:10]}, headers=admin.headers)
    assert r.json() == {"revoked": 1}
    assert client.get(ME, headers=op.headers).status_code == 401
    assert client.get(ME, headers={"Authorization": f"Bearer {second}"}).status_code == 200


def test_tokens_short_prefix_is_422(client, factory):
    admin = factory.user("admin")
    assert client.post("/api/v1/tokens/revoke", json={"prefix": "tl_"}, headers=admin.headers).status_code == 422


def test_tokens_disabled_user_is_refused_at_once(client, factory):
    admin, op = factory.user("admin"), factory.user("operator")
    assert client.get(ME, headers=op.headers).status_code == 200
    assert client.post(f"/api/v1/users/{op.id}/disable", headers=admin.headers).json()["active"] is False
    assert client.get(ME, headers=op.headers).status_code == 401
    client.post(f"/api/v1/users/{op.id}/enable", headers=admin.headers)
    assert client.get(ME, headers=op.headers).status_code == 200


def test_tokens_expire(client, factory, db):
    op = factory.user("operator")
    with db.write() as s:
        token = s.query(ApiToken).filter(ApiToken.user_id == op.id).one()
        assert token.expires_at > utcnow() + timedelta(days=89)  # the default: 90 days
        token.expires_at = utcnow() - timedelta(seconds=1)
        s.commit()
    assert client.get(ME, headers=op.headers).status_code == 401


def test_tokens_expiry_is_settable_per_token(client, factory):
    admin, op = factory.user("admin"), factory.user("operator")
    client.post(f"/api/v1/users/{op.id}/tokens", json={"expires_days": 2}, headers=admin.headers)
    tokens = client.get(f"/api/v1/users/{op.id}/tokens", headers=admin.headers).json()
    assert len(tokens) == 2 and "token" not in tokens[1]
    assert tokens[1]["expires_at"] < tokens[0]["expires_at"]


def test_tokens_database_edit_takes_effect_without_delay(settings, db, factory):
    # defect 13: after a database edit the token kept working for 10 s (a lookup cache)
    from fastapi.testclient import TestClient

    op = factory.user("operator")
    with TestClient(create_app(settings, db=db)) as c:
        assert c.get(ME, headers=op.headers).status_code == 200
        with db.write() as s:
            s.query(ApiToken).filter(ApiToken.user_id == op.id).update({"revoked_at": utcnow()})
            s.commit()
        assert c.get(ME, headers=op.headers).status_code == 401


@pytest.fixture
def cli_env(tmp_path, monkeypatch):
    monkeypatch.setenv("TRACKLABEL_DATA_DIR", str(tmp_path))
    monkeypatch.delenv("TRACKLABEL_DATABASE_URL", raising=False)


def _whoami(tmp_path, token):
    from app import crud
    from app.core.db import Database

    db = Database.from_url(f"sqlite:///{tmp_path / 'tracklabel.db'}")
    with db.read() as s:
        user = crud.user_for_token(s, token)
    db.dispose()
    return user


def test_tokens_cli_revoke_disable_and_expiry(cli_env, tmp_path):
    runner = CliRunner()
    first = runner.invoke(cli, ["user", "add", "dana", "--expires-days", "1"]).output.strip()
    second = runner.invoke(cli, ["user", "token", "dana"]).output.strip()
    assert _whoami(tmp_path, first) is not None and _whoami(tmp_path, second) is not None
    r = runner.invoke(cli, ["user", "revoke", "--token-prefix", first[:10]])
    assert r.exit_code == 0 and "revoked 1" in r.output
    assert _whoami(tmp_path, first) is None and _whoami(tmp_path, second) is not None
    assert runner.invoke(cli, ["user", "disable", "dana"]).exit_code == 0
    assert _whoami(tmp_path, second) is None
    assert runner.invoke(cli, ["user", "enable", "dana"]).exit_code == 0
    assert runner.invoke(cli, ["user", "revoke", "dana"]).exit_code == 0
    assert _whoami(tmp_path, second) is None


def test_tokens_cli_bad_input_exits_2(cli_env):
    runner = CliRunner()
    assert runner.invoke(cli, ["user", "revoke", "nobody"]).exit_code == 2
    assert runner.invoke(cli, ["user", "revoke"]).exit_code == 2
    assert runner.invoke(cli, ["user", "revoke", "--token-prefix", "tl_"]).exit_code == 2
