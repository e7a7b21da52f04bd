"""Every endpoint but /health needs a valid API token."""

from collections.abc import Iterator

import pytest
from fastapi import FastAPI
from fastapi.testclient import TestClient

from backend.config import Settings
from tests.monitoring_helpers import app_for, token_for

PROTECTED = [
    ("GET", "/api/v1/sites"),
    ("POST", "/api/v1/sites"),
    ("GET", "/api/v1/sites/1"),
    ("PATCH", "/api/v1/sites/1"),
    ("DELETE", "/api/v1/sites/1"),
    ("GET", "/api/v1/sites/1/surveys"),
    ("POST", "/api/v1/sites/1/surveys"),
    ("GET", "/api/v1/sites/1/surveys/1"),
    ("GET", "/api/v1/sites/1/surveys/1/products"),
    ("DELETE", "/api/v1/sites/1/surveys/1"),
    ("POST", "/api/v1/sites/1/surveys/sources"),
    ("PUT", "/api/v1/sites/1/surveys/1/files/{filename}"),
    ("GET", "/api/v1/sites/1/surveys/1/files"),
    ("DELETE", "/api/v1/sites/1/surveys/1/files/1"),
    ("POST", "/api/v1/sites/1/surveys/1/process"),
    ("GET", "/api/v1/sites/1/comparisons"),
    ("POST", "/api/v1/sites/1/comparisons"),
    ("GET", "/api/v1/sites/1/comparisons/1"),
    ("GET", "/api/v1/sites/1/comparisons/1/detections"),
    ("GET", "/api/v1/sites/1/comparisons/1/products"),
    ("DELETE", "/api/v1/sites/1/comparisons/1"),
    ("GET", "/api/v1/sites/1/jobs"),
    ("GET", "/api/v1/sites/1/jobs/1"),
    ("POST", "/api/v1/sites/1/jobs/1/retry"),
    ("GET", "/api/v1/sites/1/products/1"),
    ("GET", "/api/v1/sites/1/products/1/file"),
    ("GET", "/api/v1/sites/1/surveys/1/tiles/{layer}/{z}/{x}/{y}.png"),
    ("GET", "/api/v1/sites/1/comparisons/1/tiles/{layer}/{z}/{x}/{y}.png"),
    ("GET", "/api/v1/sites/1/surveys/1/tiles/{layer}/tilejson.json"),
    ("GET", "/api/v1/sites/1/comparisons/1/tiles/{layer}/tilejson.json"),
    ("GET", "/api/v1/sites/1/wmts/WMTSCapabilities.xml"),
    ("GET", "/api/v1/sites/1/surveys/1/wmts/WMTSCapabilities.xml"),
    ("GET", "/api/v1/sites/1/comparisons/1/wmts/WMTSCapabilities.xml"),
    ("GET", "/api/v1/sites/1/alerts"),
    ("PUT", "/api/v1/sites/1/alerts"),
    ("POST", "/api/v1/sites/1/webhooks"),
    ("GET", "/api/v1/sites/1/webhooks"),
    ("PATCH", "/api/v1/sites/1/webhooks/1"),
    ("DELETE", "/api/v1/sites/1/webhooks/1"),
    ("GET", "/api/v1/sites/1/deliveries"),
    ("POST", "/api/v1/sites/1/schedules"),
    ("GET", "/api/v1/sites/1/schedules"),
    ("GET", "/api/v1/sites/1/schedules/1"),
    ("PATCH", "/api/v1/sites/1/schedules/1"),
    ("DELETE", "/api/v1/sites/1/schedules/1"),
    ("POST", "/api/v1/sites/1/reports"),
    ("GET", "/api/v1/sites/1/reports"),
    ("GET", "/api/v1/sites/1/reports/1"),
    ("GET", "/api/v1/sites/1/reports/1/pdf"),
    ("GET", "/api/v1/sites/1/reports/1/html"),
    ("GET", "/api/v1/sites/1/schedules/preview"),
    ("GET", "/api/v1/sites/1/gis"),
    ("POST", "/api/v1/sites/1/webhooks/1/test"),
    ("POST", "/api/v1/sites/1/alerts/test-email"),
    ("GET", "/api/v1/sites/1/comparisons/1/detections/{file_format}"),
    ("POST", "/api/v1/auth/sign-out"),
    ("GET", "/api/v1/auth/me"),
    ("POST", "/api/v1/auth/password"),
    ("GET", "/api/v1/auth/tokens"),
    ("POST", "/api/v1/auth/tokens"),
    ("DELETE", "/api/v1/auth/tokens/1"),
    ("GET", "/api/v1/users"),
    ("POST", "/api/v1/users"),
    ("POST", "/api/v1/users/1/disable"),
    ("POST", "/api/v1/users/1/enable"),
    ("GET", "/api/v1/organisations"),
    ("POST", "/api/v1/organisations"),
    ("GET", "/api/v1/organisations/1/members"),
    ("PUT", "/api/v1/organisations/1/members/{username}"),
    ("DELETE", "/api/v1/organisations/1/members/{username}"),
    ("GET", "/api/v1/organisations/1/audit"),
    ("POST", "/api/v1/uploads"),
    ("HEAD", "/api/v1/uploads/1"),
    ("PATCH", "/api/v1/uploads/1"),
    ("DELETE", "/api/v1/uploads/1"),
    ("GET", "/api/v1/uploads/1"),
    ("GET", "/api/v1/sites/1/jobs/1/events"),
    ("PUT", "/api/v1/sites/1/comparisons/1/detections/1/feedback"),
    ("GET", "/api/v1/sites/1/comparisons/1/detections/1/feedback"),
    ("DELETE", "/api/v1/sites/1/comparisons/1/detections/1/feedback"),
    ("GET", "/api/v1/sites/1/comparisons/1/detections/1/history"),
    ("GET", "/api/v1/sites/1/uploads"),
    ("PATCH", "/api/v1/sites/1/surveys/1"),
    ("PATCH", "/api/v1/sites/1/comparisons/1"),
    ("POST", "/api/v1/sites/1/comparisons/1/profile"),
    ("POST", "/api/v1/sites/1/surveys/1/profile"),
    ("POST", "/api/v1/sites/1/comparisons/1/volume"),
    ("GET", "/api/v1/sites/1/comparisons/1/heights"),
    ("GET", "/api/v1/sites/1/surveys/1/heights"),
    ("GET", "/api/v1/sites/1/training-labels"),
    ("GET", "/api/v1/sites/1/comparisons/1/cells"),
    ("GET", "/api/v1/methods"),
    ("GET", "/api/v1/languages"),
    ("GET", "/api/v1/models"),
    ("POST", "/api/v1/models/training"),
    ("GET", "/api/v1/models/training/{name}/{run}"),
]
# Signing in is how one gets a token; OPTIONS only says which tus extensions are supported.
PUBLIC = [
    ("POST", "/api/v1/auth/sign-in"),
    ("OPTIONS", "/api/v1/uploads"),
]


def test_health_needs_no_token(client: TestClient) -> None:
    response = client.get("/health")
    assert response.status_code == 200
    assert response.json() == {"status": "ok"}


def test_every_api_route_is_listed_here(app: FastAPI) -> None:
    listed = {(method, path.replace("/1", "/{id}")) for method, path in PROTECTED + PUBLIC}
    routes = set()
    for path, operations in app.openapi()["paths"].items():
        if path.startswith("/api/v1"):
            for name in (
                "site_id",
                "survey_id",
                "comparison_id",
                "job_id",
                "product_id",
                "webhook_id",
                "schedule_id",
                "report_id",
                "file_id",
                "upload_id",
                "detection_id",
                "token_id",
                "user_id",
                "organisation_id",
            ):
                path = path.replace("{" + name + "}", "{id}")
            routes |= {(method.upper(), path) for method in operations}
    assert routes == listed


@pytest.fixture(scope="module")
def refusing(
    tmp_path_factory: pytest.TempPathFactory,
) -> Iterator[tuple[TestClient, dict[str, str]]]:
    """One app, with one valid token, for the requests below (134): each is refused before
    it reads or writes anything, and building an app for each took most of the time."""
    settings = Settings(data_dir=tmp_path_factory.mktemp("auth") / "data")
    with (
        pytest.MonkeyPatch.context() as monkeypatch,
        app_for(settings, monkeypatch) as app,
        TestClient(app) as client,
    ):
        yield client, {"Authorization": f"Bearer {token_for(app)}"}


@pytest.mark.parametrize(("method", "path"), PROTECTED)
def test_no_token_is_refused(refusing: tuple, method: str, path: str) -> None:
    client, _auth = refusing
    response = client.request(method, path)
    assert response.status_code == 401
    if method != "HEAD":  # a HEAD answer has no body
        assert "missing API token" in response.json()["detail"]
    assert response.headers["WWW-Authenticate"] == "Bearer"


@pytest.mark.parametrize(("method", "path"), PROTECTED)
def test_wrong_token_is_refused(refusing: tuple, method: str, path: str) -> None:
    client, _auth = refusing  # a valid token exists: the wrong one is still refused
    response = client.request(method, path, headers={"Authorization": "Bearer sw_not-a-token"})
    assert response.status_code == 401
    if method != "HEAD":
        assert "invalid" in response.json()["detail"]


def test_token_is_stored_hashed(app: FastAPI, auth: dict) -> None:
    from sqlalchemy import select

    from backend.db.models import ApiToken

    secret = auth["Authorization"].removeprefix("Bearer ")
    with app.state.sessionmaker() as session:
        stored = session.scalars(select(ApiToken)).one()
    assert secret not in (stored.token_hash, stored.prefix)
    assert len(stored.token_hash) == 64


def test_revoked_token_is_refused(client: TestClient, app: FastAPI, auth: dict) -> None:
    from datetime import UTC, datetime

    from sqlalchemy import update

    from backend.db.models import ApiToken

    assert client.get("/api/v1/sites", headers=auth).status_code == 200
    with app.state.sessionmaker() as session:
        session.execute(update(ApiToken).values(revoked_at=datetime.now(UTC)))
        session.commit()
    assert client.get("/api/v1/sites", headers=auth).status_code == 401
