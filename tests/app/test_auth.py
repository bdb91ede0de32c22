from __future__ import annotations

from sqlalchemy import select

from app.core.security import hash_token
from app.models import ApiToken


def test_auth_missing_token_is_401(client):
    r = client.get("/api/v1/tracks")
    assert r.status_code == 401


def test_auth_wrong_token_is_401(client, factory):
    factory.user()
    r = client.get("/api/v1/tracks", headers={"Authorization": "Bearer tl_not-a-token"})
    assert r.status_code == 401


def test_auth_valid_token_reads_me(client, factory):
    op = factory.user("operator", name="alice")
    r = client.get("/api/v1/users/me", headers=op.headers)
    assert r.status_code == 200 and r.json()["name"] == "alice" and r.json()["role"] == "operator"


def test_auth_tokens_are_stored_hashed(factory, db):
    op = factory.user()
    with db.read() as s:
        stored = s.scalars(select(ApiToken.token_hash).where(ApiToken.user_id == op.id)).all()
    assert stored == [hash_token(op.token)] and op.token not in stored


def test_auth_operator_on_admin_route_is_403(client, factory):
    op = factory.user("operator")
    assert client.get("/api/v1/users", headers=op.headers).status_code == 403
    assert client.post("/api/v1/datasets", json={"path": "x"}, headers=op.headers).status_code == 403


def test_auth_admin_creates_user_with_token_shown_once(client, factory):
    admin = factory.user("admin")
    r = client.post("/api/v1/users", json={"name": "bob", "role": "operator"}, headers=admin.headers)
    assert r.status_code == 201, r.text
    token = r.json()["token"]
    me = client.get("/api/v1/users/me", headers={"Authorization": f"Bearer {token}"})
    assert me.json()["name"] == "bob"
    listing = client.get("/api/v1/users", headers=admin.headers).text
    assert token not in listing


def test_auth_duplicate_user_is_409(client, factory):
    admin = factory.user("admin")
    body = {"name": "carol", "role": "operator"}
    assert client.post("/api/v1/users", json=body, headers=admin.headers).status_code == 201
    assert client.post("/api/v1/users", json=body, headers=admin.headers).status_code == 409


def test_auth_health_needs_no_token(client):
    r = client.get("/api/v1/health")
    assert r.status_code == 200 and r.json()["status"] == "ok"
    assert client.get("/health").status_code == 200
