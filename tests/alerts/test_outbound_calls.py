"""Outbound calls that cannot be turned inward: webhook URLs to anything but public
addresses are refused when saved and when called, redirects are answers, and e-mail
recipients cannot add headers."""

from pathlib import Path

import pytest
from fastapi import FastAPI
from fastapi.testclient import TestClient
from sqlalchemy import update

from backend.config import Settings
from backend.db.models import AlertSettings, Site
from backend.services.alerts import attempt_delivery, create_deliveries
from tests.monitoring_helpers import MailReceiver, WebhookReceiver

INWARD = [
    ("http://127.0.0.1:8123/hook", "loopback"),
    ("http://[::1]:8000/", "loopback"),
    ("http://localhost:8123/api/v1/sites", "loopback"),
    ("http://169.254.169.254/latest/meta-data/", "link-local"),
    ("http://[fe80::1]/", "link-local"),
    ("http://0x7f000001/", "loopback"),
    ("http://2130706433/", "loopback"),
    ("http://0177.0.0.1/", "loopback"),
    ("http://127.1/", "loopback"),
    ("http://[::ffff:127.0.0.1]/", "loopback"),
    ("http://[::ffff:a9fe:a9fe]/", "link-local"),
    ("http://[64:ff9b::a00:1]/", "private"),
    ("http://10.0.0.1/", "private"),
    ("http://192.168.1.20:8080/", "private"),
    ("http://172.16.5.4/", "private"),
    ("http://[fd00::1]/", "private"),
    ("http://100.64.0.1/", "not a public address"),
    ("http://224.0.0.1/", "multicast"),
    ("http://[ff02::1]/", "multicast"),
    ("http://0.0.0.0:8000/", "unspecified"),
    ("http://[::]/", "unspecified"),
]


@pytest.fixture
def alert_settings(tmp_path: Path, mailbox: MailReceiver) -> Settings:
    """As a deployment has them by default: no network allowed besides the public one."""
    return Settings(
        data_dir=tmp_path / "data",
        smtp_host="127.0.0.1",
        smtp_port=mailbox.port,
        delivery_max_attempts=3,
        delivery_retry_base_s=0.3,
    )


def _site(client: TestClient, auth: dict, name: str = "watched") -> int:
    return client.post("/api/v1/sites", json={"name": name}, headers=auth).json()["id"]


def _failure(site: Site) -> dict:
    job = {"id": 1, "kind": "comparison", "error": "the disk is full"}
    return {"event": "job_failed", "site": {"id": site.id, "name": site.name}, "job": job}


def _alert(app: FastAPI, site_id: int) -> list[int]:
    """A job_failed event of the site, as the job layer raises it: its deliveries' ids."""
    with app.state.sessionmaker() as session:
        site = session.get(Site, site_id)
        created = create_deliveries(
            session, app.state.settings, site, "job_failed", "job:1", _failure(site), "failed"
        )
        session.commit()
        return [d.id for d in created]


def _attempt(app: FastAPI, delivery_id: int, settings: Settings | None = None):
    settings = settings or app.state.settings
    return attempt_delivery(delivery_id, app.state.sessionmaker, app.state.storage, settings)


@pytest.mark.parametrize(("url", "kind"), INWARD, ids=[u for u, _ in INWARD])
def test_a_webhook_to_an_inward_address_is_refused(
    client: TestClient, auth: dict, url: str, kind: str
) -> None:
    site = _site(client, auth)
    response = client.post(f"/api/v1/sites/{site}/webhooks", json={"url": url}, headers=auth)
    assert response.status_code == 422, response.text
    detail = response.json()["detail"]
    assert kind in detail and "SLIDEWATCH_WEBHOOK_ALLOWED_NETWORKS" in detail
    assert client.get(f"/api/v1/sites/{site}/webhooks", headers=auth).json() == []


@pytest.mark.parametrize(
    ("url", "says"),
    [
        ("http://user:secret@example.com/hook", "user name or password"),
        ("https://token@example.com/hook", "user name or password"),
        ("http://example.com:99999/", "not a URL"),
        ("http://exa mple.com/", "spaces or control characters"),
        ("file:///etc/passwd", "not an http(s) URL"),
        ("http://name.invalid/hook", "cannot be resolved"),
    ],
)
def test_a_webhook_url_with_credentials_or_no_host_is_refused(
    client: TestClient, auth: dict, url: str, says: str
) -> None:
    site = _site(client, auth)
    response = client.post(f"/api/v1/sites/{site}/webhooks", json={"url": url}, headers=auth)
    assert response.status_code == 422 and says in response.text, response.text


def test_an_allowed_network_is_called_and_checked_again_at_call_time(
    alert_app: FastAPI, client: TestClient, auth: dict
) -> None:
    """On premises a receiver may be allowed; the check is repeated at every call, so
    what is no longer allowed (or a name that now resolves elsewhere) is not called."""
    alert_app.state.settings.webhook_allowed_networks = ["127.0.0.1/32"]
    site = _site(client, auth)
    with WebhookReceiver() as receiver:
        for refused in ("http://127.0.0.2/", "http://[::1]/"):  # outside the network
            hook = client.post(
                f"/api/v1/sites/{site}/webhooks", json={"url": refused}, headers=auth
            )
            assert hook.status_code == 422
        hook = client.post(
            f"/api/v1/sites/{site}/webhooks", json={"url": receiver.url}, headers=auth
        )
        assert hook.status_code == 201
        [first] = _alert(alert_app, site)
        assert _attempt(alert_app, first).delivered
        assert len(receiver.requests) == 1

        no_longer = alert_app.state.settings.model_copy(update={"webhook_allowed_networks": []})
        with alert_app.state.sessionmaker() as session:
            site_row = session.get(Site, site)
            [second] = create_deliveries(
                session, no_longer, site_row, "job_failed", "job:2", _failure(site_row), "failed"
            )
            session.commit()
            second_id = second.id
        outcome = _attempt(alert_app, second_id, no_longer)
        assert not outcome.delivered and outcome.error.startswith("refused: ")
        assert "loopback" in outcome.error
        assert len(receiver.requests) == 1  # nothing reached the receiver
    [logged] = [
        d
        for d in client.get(f"/api/v1/sites/{site}/deliveries", headers=auth).json()
        if d["id"] == second_id
    ]
    assert logged["status"] == "retrying" and logged["attempt_log"][0]["error"].startswith(
        "refused"
    )


def test_a_redirect_is_an_answer_and_is_not_followed(
    alert_app: FastAPI, client: TestClient, auth: dict
) -> None:
    alert_app.state.settings.webhook_allowed_networks = ["127.0.0.1/32"]
    site = _site(client, auth)
    with WebhookReceiver(statuses=[307]) as receiver:
        client.post(f"/api/v1/sites/{site}/webhooks", json={"url": receiver.url}, headers=auth)
        [delivery] = _alert(alert_app, site)
        outcome = _attempt(alert_app, delivery)
        assert not outcome.delivered and outcome.status_code == 307
        assert len(receiver.requests) == 1


@pytest.mark.parametrize(
    "address",
    [
        "geo@town.example\r\nBcc: spy@evil.example",
        "geo@town.example\nSubject: free money",
        "geo\x00@town.example",
        "nobody",
        "geo@localhost",
        "geo town@town.example",
        "<geo@town.example>",
        "geo@town.example, spy@evil.example",
        "geo@-town.example",
        "geo@town.123",
    ],
)
def test_an_email_recipient_that_is_not_a_plain_address_is_refused(
    client: TestClient, auth: dict, address: str
) -> None:
    site = _site(client, auth)
    response = client.put(
        f"/api/v1/sites/{site}/alerts", json={"email_recipients": [address]}, headers=auth
    )
    assert response.status_code == 422 and "is not an e-mail address" in response.text
    assert client.get(f"/api/v1/sites/{site}/alerts", headers=auth).json()["email_recipients"] == []


def test_plain_addresses_are_taken_and_the_subject_stays_one_line(
    alert_app: FastAPI, client: TestClient, auth: dict, mailbox: MailReceiver
) -> None:
    site = _site(client, auth)
    recipients = ["geo@town.example", "o'brien+alerts@sub.town-hall.example"]
    put = client.put(
        f"/api/v1/sites/{site}/alerts", json={"email_recipients": recipients}, headers=auth
    )
    assert put.status_code == 200
    with alert_app.state.sessionmaker() as session:  # a name with a line break in it
        session.execute(update(Site).values(name="East\r\nBcc: spy@evil.example"))
        session.commit()
    with alert_app.state.sessionmaker() as session:
        site_row = session.get(Site, site)
        created = create_deliveries(
            session,
            alert_app.state.settings,
            site_row,
            "job_failed",
            "job:9",
            _failure(site_row),
            f"[slidewatch] {site_row.name}: job failed",
        )
        session.commit()
        delivery = created[0].id
    assert _attempt(alert_app, delivery).delivered
    [message] = mailbox.messages
    assert message["To"] == ", ".join(recipients)
    assert message["Bcc"] is None and "\n" not in message["Subject"]


def test_a_recipient_saved_before_the_check_fails_the_attempt_and_says_why(
    alert_app: FastAPI, client: TestClient, auth: dict, mailbox: MailReceiver
) -> None:
    site = _site(client, auth)
    client.put(
        f"/api/v1/sites/{site}/alerts", json={"email_recipients": ["a@b.example"]}, headers=auth
    )
    with alert_app.state.sessionmaker() as session:
        session.execute(
            update(AlertSettings).values(email_recipients=["a@b.example\r\nBcc: spy@evil.example"])
        )
        session.commit()
    [delivery] = _alert(alert_app, site)
    outcome = _attempt(alert_app, delivery)
    assert not outcome.delivered and "CR or LF" in outcome.error
    assert mailbox.messages == []
    [logged] = client.get(f"/api/v1/sites/{site}/deliveries", headers=auth).json()
    assert logged["status"] == "retrying" and logged["attempts"] == 1
    assert "CR or LF" in logged["attempt_log"][0]["error"]
