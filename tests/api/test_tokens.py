"""API tokens that are listed, expire and are revoked; passwords changed; users disabled;
tokens kept out of the logs and out of the links the API returns."""

import logging
from datetime import UTC, datetime, timedelta

import pytest
from click.testing import CliRunner
from fastapi import FastAPI
from fastapi.testclient import TestClient
from sqlalchemy import update

from backend.cli import ensure_admin_token, main
from backend.db.models import ApiToken
from backend.services.users import create_user
from tests.api_helpers import upload_dsm
from worker.simulator.dsm_pair import DsmPairPaths

MARIA = {"username": "maria", "password": "landslide-2026"}


@pytest.fixture
def maria(app: FastAPI, client: TestClient) -> dict[str, str]:
    """Maria signed in: the Authorization header of her session."""
    with app.state.sessionmaker() as session:
        create_user(session, MARIA["username"], MARIA["password"], "Maria Rossi")
        session.commit()
    token = client.post("/api/v1/auth/sign-in", json=MARIA).json()["token"]
    return {"Authorization": f"Bearer {token}"}


def bearer(token: str) -> dict[str, str]:
    return {"Authorization": f"Bearer {token}"}


def test_tokens_are_made_with_an_expiry_listed_and_revoked(client: TestClient, auth: dict) -> None:
    made = client.post("/api/v1/auth/tokens", json={"name": "qgis"}, headers=auth)
    assert made.status_code == 201
    body = made.json()
    expires = datetime.fromisoformat(body["expires_at"])
    assert abs(expires - (datetime.now(UTC) + timedelta(days=90))) < timedelta(minutes=1)
    assert body["kind"] == "api" and body["token"].startswith(body["prefix"])
    assert client.get("/api/v1/sites", headers=bearer(body["token"])).status_code == 200

    listed = client.get("/api/v1/auth/tokens", headers=auth).json()
    assert {t["name"] for t in listed} == {"tests", "qgis"}
    assert all("token" not in t for t in listed)  # the secret is shown once only
    assert [t["current"] for t in listed if t["name"] == "tests"] == [True]

    assert client.delete(f"/api/v1/auth/tokens/{body['id']}", headers=auth).status_code == 204
    assert client.get("/api/v1/sites", headers=bearer(body["token"])).status_code == 401
    assert [t["name"] for t in client.get("/api/v1/auth/tokens", headers=auth).json()] == ["tests"]
    ended = client.get("/api/v1/auth/tokens?include_ended=true", headers=auth).json()
    assert [t["revoked_at"] is not None for t in ended if t["name"] == "qgis"] == [True]
    assert client.delete("/api/v1/auth/tokens/999", headers=auth).status_code == 404


def test_a_token_expires(client: TestClient, auth: dict, app: FastAPI) -> None:
    too_long = client.post("/api/v1/auth/tokens", json={"name": "x", "days": 400}, headers=auth)
    assert too_long.status_code == 422 and "SLIDEWATCH_TOKEN_MAX_DAYS" in too_long.text
    made = client.post("/api/v1/auth/tokens", json={"name": "short", "days": 1}, headers=auth)
    secret = made.json()["token"]
    with app.state.sessionmaker() as session:
        session.execute(
            update(ApiToken)
            .where(ApiToken.id == made.json()["id"])
            .values(expires_at=datetime.now(UTC) - timedelta(seconds=1))
        )
        session.commit()
    assert client.get("/api/v1/sites", headers=bearer(secret)).status_code == 401


def test_a_user_sees_and_revokes_only_their_own_tokens(
    client: TestClient, auth: dict, maria: dict
) -> None:
    own = client.post("/api/v1/auth/tokens", json={"name": "script"}, headers=maria).json()
    listed = client.get("/api/v1/auth/tokens", headers=maria).json()
    assert sorted((t["kind"], t["name"]) for t in listed) == [
        ("api", "script"),
        ("session", "map session of maria"),
    ]
    platform = client.get("/api/v1/auth/tokens", headers=auth).json()
    assert [t["name"] for t in platform] == ["tests"]
    assert (
        client.delete(f"/api/v1/auth/tokens/{platform[0]['id']}", headers=maria).status_code == 404
    )
    assert client.delete(f"/api/v1/auth/tokens/{own['id']}", headers=maria).status_code == 204


def test_changing_the_password_ends_every_session_and_token(
    client: TestClient, maria: dict
) -> None:
    script = client.post("/api/v1/auth/tokens", json={"name": "s"}, headers=maria).json()
    wrong = client.post(
        "/api/v1/auth/password",
        json={"current_password": "not-it-at-all", "new_password": "pendio-franoso-7"},
        headers=maria,
    )
    assert wrong.status_code == 403
    weak = client.post(
        "/api/v1/auth/password",
        json={"current_password": MARIA["password"], "new_password": "password123"},
        headers=maria,
    )
    assert weak.status_code == 422 and "most common" in weak.json()["detail"]
    changed = client.post(
        "/api/v1/auth/password",
        json={"current_password": MARIA["password"], "new_password": "pendio-franoso-7"},
        headers=maria,
    )
    assert changed.status_code == 204
    assert client.get("/api/v1/sites", headers=maria).status_code == 401
    assert client.get("/api/v1/sites", headers=bearer(script["token"])).status_code == 401
    assert client.post("/api/v1/auth/sign-in", json=MARIA).status_code == 401
    again = client.post(
        "/api/v1/auth/sign-in", json={"username": "maria", "password": "pendio-franoso-7"}
    )
    assert again.status_code == 200


def test_an_api_token_has_no_password(client: TestClient, auth: dict) -> None:
    body = {"current_password": "whatever-1", "new_password": "whatever-2"}
    assert client.post("/api/v1/auth/password", json=body, headers=auth).status_code == 409


def test_an_administrator_disables_and_enables_a_user(
    client: TestClient, auth: dict, maria: dict
) -> None:
    users = client.get("/api/v1/users", headers=auth).json()
    [account] = [u for u in users if u["username"] == "maria"]
    assert client.get("/api/v1/users", headers=maria).status_code == 403
    assert client.post(f"/api/v1/users/{account['id']}/disable", headers=maria).status_code == 403

    disabled = client.post(f"/api/v1/users/{account['id']}/disable", headers=auth)
    assert disabled.status_code == 200 and disabled.json()["disabled_at"]
    assert client.get("/api/v1/sites", headers=maria).status_code == 401
    assert client.post("/api/v1/auth/sign-in", json=MARIA).status_code == 401
    client.post(f"/api/v1/users/{account['id']}/enable", headers=auth)
    assert client.post("/api/v1/auth/sign-in", json=MARIA).status_code == 200
    assert client.post("/api/v1/users/999/disable", headers=auth).status_code == 404


def test_the_access_log_never_holds_a_token(app: FastAPI, auth: dict) -> None:
    """uvicorn writes each request line to `uvicorn.access`; the app filters it."""
    secret = auth["Authorization"].removeprefix("Bearer ")
    lines: list[str] = []

    class Keep(logging.Handler):
        def emit(self, record: logging.LogRecord) -> None:
            lines.append(record.getMessage())

    access = logging.getLogger("uvicorn.access")
    handler, level = Keep(), access.level
    access.addHandler(handler)
    access.setLevel(logging.INFO)
    try:
        # As uvicorn's access logger writes it: client, method, path with query, version.
        access.info(
            '%s - "%s %s HTTP/%s" %d',
            "127.0.0.1:5000",
            "GET",
            f"/ogc/collections?api_key={secret}&limit=5",
            "1.1",
            200,
        )
    finally:
        access.removeHandler(handler)
        access.setLevel(level)
    assert lines == [
        '127.0.0.1:5000 - "GET /ogc/collections?api_key=[redacted]&limit=5 HTTP/1.1" 200'
    ]


def test_tilejson_and_wmts_carry_no_token_and_ignore_the_host_header(
    client: TestClient, auth: dict, app: FastAPI, dsm_pair_files: DsmPairPaths
) -> None:
    secret = auth["Authorization"].removeprefix("Bearer ")
    site = client.post("/api/v1/sites", json={"name": "slope"}, headers=auth).json()["id"]
    survey = upload_dsm(client, auth, site, dsm_pair_files.pre, "2026-06-01T10:00:00Z")["id"]
    app.state.settings.public_url = "https://slidewatch.example"
    spoofed = {"Host": "evil.example"}
    tilejson = client.get(
        f"/api/v1/sites/{site}/surveys/{survey}/tiles/dsm/tilejson.json?api_key={secret}",
        headers=spoofed,
    ).json()
    [template] = tilejson["tiles"]
    assert template.startswith("https://slidewatch.example/api/v1/") and secret not in template
    wmts = client.get(
        f"/api/v1/sites/{site}/wmts/WMTSCapabilities.xml?api_key={secret}", headers=spoofed
    )
    assert wmts.status_code == 200
    assert secret not in wmts.text and "evil.example" not in wmts.text
    assert "https://slidewatch.example/api/v1/" in wmts.text


def test_token_and_user_commands(app: FastAPI, client: TestClient, maria: dict) -> None:
    made = CliRunner().invoke(main, ["create-token", "--name", "qgis", "--days", "7"])
    assert made.exit_code == 0, made.output
    token = made.output.strip()
    listed = client.get("/api/v1/auth/tokens", headers=bearer(token)).json()
    [qgis] = [t for t in listed if t["name"] == "qgis"]
    expires = datetime.fromisoformat(qgis["expires_at"])
    assert abs(expires - (datetime.now(UTC) + timedelta(days=7))) < timedelta(minutes=1)
    too_long = CliRunner().invoke(main, ["create-token", "--days", "999"])
    assert too_long.exit_code != 0 and "at most 365" in too_long.output

    assert CliRunner().invoke(main, ["disable-user", "maria"]).exit_code == 0
    assert client.get("/api/v1/sites", headers=maria).status_code == 401
    assert client.post("/api/v1/auth/sign-in", json=MARIA).status_code == 401
    assert CliRunner().invoke(main, ["enable-user", "maria"]).exit_code == 0
    assert client.post("/api/v1/auth/sign-in", json=MARIA).status_code == 200
    assert "no user named" in CliRunner().invoke(main, ["disable-user", "nobody"]).output


def test_the_operators_token_is_made_again_once_it_has_ended(
    app: FastAPI, client: TestClient
) -> None:
    settings = app.state.settings
    first = ensure_admin_token(settings)
    assert client.get("/api/v1/sites", headers=bearer(first)).status_code == 200
    assert ensure_admin_token(settings) == first  # still valid: kept
    listed = client.get("/api/v1/auth/tokens", headers=bearer(first)).json()
    [mine] = [t for t in listed if t["current"]]
    client.delete(f"/api/v1/auth/tokens/{mine['id']}", headers=bearer(first))
    second = ensure_admin_token(settings)
    assert second != first
    assert client.get("/api/v1/sites", headers=bearer(second)).status_code == 200
