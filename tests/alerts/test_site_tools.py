"""What the page's Alerts, GIS and Users panels use: test deliveries to a webhook and to
the e-mail recipients, e-mail refused with the reason without SMTP, the GIS addresses,
and users made by the platform administrator."""

from pathlib import Path

import pytest
from fastapi import FastAPI
from fastapi.testclient import TestClient

from backend.config import Settings
from backend.services.alerts import attempt_delivery
from tests.monitoring_helpers import MailReceiver, WebhookReceiver, app_for, token_for


def _attempt(app: FastAPI, delivery_id: int) -> None:
    attempt_delivery(delivery_id, app.state.sessionmaker, app.state.storage, app.state.settings)


def test_a_test_delivery_reaches_the_webhook_and_the_mailbox(
    alert_app: FastAPI, client: TestClient, auth: dict, mailbox: MailReceiver
) -> None:
    site = client.post("/api/v1/sites", json={"name": "tested"}, headers=auth).json()["id"]
    with WebhookReceiver() as receiver:
        hook = client.post(
            f"/api/v1/sites/{site}/webhooks", json={"url": receiver.url}, headers=auth
        ).json()
        sent = client.post(f"/api/v1/sites/{site}/webhooks/{hook['id']}/test", headers=auth)
        assert sent.status_code == 202, sent.text
        assert sent.json()["event"] == "test" and sent.json()["status"] == "pending"
        _attempt(alert_app, sent.json()["id"])
        [(headers, body, _)] = receiver.requests
        assert headers["X-Slidewatch-Event"] == "test" and b'"event":"test"' in body
    # A second test is a delivery of its own, not refused as a duplicate.
    again = client.post(f"/api/v1/sites/{site}/webhooks/{hook['id']}/test", headers=auth)
    assert again.status_code == 202 and again.json()["id"] != sent.json()["id"]

    no_one = client.post(f"/api/v1/sites/{site}/alerts/test-email", headers=auth)
    assert no_one.status_code == 409 and "no e-mail recipients" in no_one.json()["detail"]
    put = client.put(
        f"/api/v1/sites/{site}/alerts",
        json={"email_recipients": ["duty@town.example"]},
        headers=auth,
    )
    assert put.status_code == 200 and put.json()["email_available"] is True
    mail = client.post(f"/api/v1/sites/{site}/alerts/test-email", headers=auth)
    assert mail.status_code == 202, mail.text
    _attempt(alert_app, mail.json()["id"])
    [message] = mailbox.messages
    assert message["To"] == "duty@town.example" and "test e-mail" in message["Subject"]

    log = client.get(f"/api/v1/sites/{site}/deliveries", headers=auth).json()
    delivered = {d["id"]: d["status"] for d in log}
    assert delivered[sent.json()["id"]] == "delivered"
    assert delivered[mail.json()["id"]] == "delivered"


def test_e_mail_is_refused_with_the_reason_without_smtp(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    with app_for(Settings(data_dir=tmp_path / "data"), monkeypatch) as app:
        auth = {"Authorization": f"Bearer {token_for(app)}"}
        with TestClient(app) as client:
            site = client.post("/api/v1/sites", json={"name": "s"}, headers=auth).json()["id"]
            shown = client.get(f"/api/v1/sites/{site}/alerts", headers=auth).json()
            assert shown["email_available"] is False
            assert "SLIDEWATCH_SMTP_HOST" in shown["email_unavailable_reason"]
            put = client.put(
                f"/api/v1/sites/{site}/alerts",
                json={"email_recipients": ["a@b.example"]},
                headers=auth,
            )
            assert put.status_code == 409 and "SLIDEWATCH_SMTP_HOST is unset" in put.text
            stored = client.get(f"/api/v1/sites/{site}/alerts", headers=auth).json()
            assert stored["email_recipients"] == []
            # Thresholds alone are still taken.
            assert (
                client.put(
                    f"/api/v1/sites/{site}/alerts", json={"min_area_m2": 50}, headers=auth
                ).status_code
                == 200
            )
            test = client.post(f"/api/v1/sites/{site}/alerts/test-email", headers=auth)
            assert test.status_code == 409 and "no SMTP server" in test.json()["detail"]


def test_gis_addresses_come_from_the_public_url_without_a_token(
    client: TestClient, auth: dict
) -> None:
    site = client.post("/api/v1/sites", json={"name": "gis"}, headers=auth).json()["id"]
    links = client.get(f"/api/v1/sites/{site}/gis", headers=auth)
    assert links.status_code == 200, links.text
    body = links.json()
    assert body["ogc_api"] == "https://slidewatch.example/ogc"
    assert body["wmts"] == (
        f"https://slidewatch.example/api/v1/sites/{site}/wmts/WMTSCapabilities.xml"
    )
    assert body["stac"] == f"https://slidewatch.example/stac/sites/{site}/collection.json"
    token = auth["Authorization"].split()[1]
    assert token not in links.text and "api_key=" not in links.text.replace("'?api_key=", "")
    # Each address answers.
    for url in (body["ogc_api"], body["wmts"], body["stac"]):
        path = url.removeprefix("https://slidewatch.example")
        assert client.get(path, headers=auth).status_code == 200, path


def test_the_platform_administrator_creates_users(client: TestClient, auth: dict) -> None:
    made = client.post(
        "/api/v1/users",
        json={"username": "kenji", "password": "slope-watch-77", "display_name": "Kenji"},
        headers=auth,
    )
    assert made.status_code == 201, made.text
    assert made.json()["username"] == "kenji"
    again = client.post(
        "/api/v1/users", json={"username": "kenji", "password": "slope-watch-77"}, headers=auth
    )
    assert again.status_code == 422 and "exists" in again.json()["detail"]
    signed_in = client.post(
        "/api/v1/auth/sign-in", json={"username": "kenji", "password": "slope-watch-77"}
    )
    assert signed_in.status_code == 200, signed_in.text
