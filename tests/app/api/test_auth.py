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


def test_auth_issued_token_records_the_issuing_admin(client, factory, db):
    admin = factory.user("admin")
    op = factory.user("operator")
    r = client.post(f"/api/v1/users/{op.id}/tokens", headers=admin.headers)
    assert r.status_code == 201, r.text
    with db.read() as s:
        row = s.scalars(select(ApiToken).where(ApiToken.token_hash == hash_token(r.json()["token"]))).one()
    assert row.user_id == op.id and row.created_by_id == admin.id


def test_auth_duplicate_user_is_409(client, factory):
    admin = factory.user("admin")
    body = {"name": "carol", "role": "operator"}
    assert client.post("/api/v1/users", json=body, headers=admin.headers).status_code == 201
    assert client.post("/api/v1/users", json=body, headers=admin.headers).status_code == 409


def test_auth_health_needs_no_token(client):
    r = client.get("/api/v1/health")
    assert r.status_code == 200 and r.json()["status"] == "ok"
    assert client.get("/health").status_code == 200


def _secured_operations(client) -> list[tuple[str, str]]:
    """(method, path) of every operation the OpenAPI schema marks as needing a token; path
    parameters filled with 1."""
    import re

    paths = client.get("/api/v1/openapi.json").json()["paths"]
    return [
        (method.upper(), re.sub(r"\{[^}]+\}", "1", path))
        for path, ops in paths.items()
        for method, op in ops.items()
        if op.get("security")
    ]


def test_auth_every_secured_route_refuses_missing_and_wrong_tokens(client, factory):
    factory.user("admin")
    client.app.state.auth_limit.limit = 10**6  # every route's own answer, not the limit's 429
    ops = _secured_operations(client)
    assert len(ops) >= 25
    bad = []
    for method, path in ops:
        for headers in ({}, {"Authorization": "Bearer tl_not-a-token"}, {"Authorization": "Basic dTpw"}):
            code = client.request(method, path, headers=headers, json={}).status_code
            if code != 401:
                bad.append(f"{method} {path} {headers}: {code}")
    assert not bad, bad


ADMIN_ROUTES = [
    ("GET", "/api/v1/users"),
    ("POST", "/api/v1/users"),
    ("POST", "/api/v1/users/1/tokens"),
    ("GET", "/api/v1/datasets"),
    ("POST", "/api/v1/datasets"),
    ("GET", "/api/v1/datasets/1"),
    ("POST", "/api/v1/sequences/1/ingest"),
]


def test_auth_operator_gets_403_on_every_admin_route(client, factory):
    factory.registered_sequence()
    op = factory.user("operator")
    bodies = {"/api/v1/users": {"name": "mallory", "role": "admin"}, "/api/v1/datasets": {"path": "seq"}}
    codes = {
        (m, p): client.request(m, p, json=bodies.get(p, {}), headers=op.headers).status_code for m, p in ADMIN_ROUTES
    }
    assert set(codes.values()) == {403}, codes


def test_auth_failed_tokens_are_rate_limited_with_retry_after(client, factory, settings):
    op = factory.user("operator")
    for _ in range(settings.auth_failures_per_minute):
        assert client.get("/api/v1/users/me", headers={"Authorization": "Bearer tl_wrong"}).status_code == 401
    r = client.get("/api/v1/users/me", headers={"Authorization": "Bearer tl_wrong"})
    assert r.status_code == 429 and 1 <= int(r.headers["Retry-After"]) <= 60, r.headers
    # the address waits, whatever it sends; missing tokens are not counted
    assert client.get("/api/v1/users/me", headers=op.headers).status_code == 429
    client.app.state.auth_limit.window_s = 0.0  # the minute has passed
    assert client.get("/api/v1/users/me", headers=op.headers).status_code == 200


def test_auth_every_answer_carries_the_security_headers(client, factory):
    admin = factory.user("admin")
    for r in (client.get("/api/v1/users/me", headers=admin.headers),
              client.post("/api/v1/users", json={"name": "new"}, headers=admin.headers),
              client.get("/api/v1/nothing-here"), client.post("/api/v1/users/me", headers=admin.headers)):
        assert r.headers["x-content-type-options"] == "nosniff" and "default-src 'none'" in r.headers["content-security-policy"]
        assert r.headers["cache-control"] == "no-store", r.url  # the new token's answer above included


def test_auth_405_lists_every_allowed_method(client, factory):
    admin = factory.user("admin")
    r = client.delete("/api/v1/jobs", headers=admin.headers)
    assert r.status_code == 405 and r.headers["allow"] == "GET, POST"
