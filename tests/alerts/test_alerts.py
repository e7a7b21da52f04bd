"""Alerts: thresholds decide, webhooks are signed and retried with a logged attempt each,
e-mails reach an SMTP server, job failures alert, and nothing is delivered twice."""

import json
import time

import pytest
from fastapi import FastAPI
from fastapi.testclient import TestClient

from backend.services.alerts import attempt_delivery
from backend.signing import SIGNATURE_HEADER, TIMESTAMP_HEADER, verify_signature
from tests.api_helpers import job_context
from tests.monitoring_helpers import MailReceiver, WebhookReceiver, finished_comparison
from worker.jobs.runner import fail_job
from worker.simulator.dsm_pair import DsmPairPaths


def _site_with_webhook(client: TestClient, auth: dict, url: str, **alerts) -> tuple[int, dict]:
    site = client.post("/api/v1/sites", json={"name": "watched"}, headers=auth).json()["id"]
    put = client.put(f"/api/v1/sites/{site}/alerts", json=alerts, headers=auth)
    assert put.status_code == 200, put.text
    hook = client.post(f"/api/v1/sites/{site}/webhooks", json={"url": url}, headers=auth)
    assert hook.status_code == 201, hook.text
    return site, hook.json()


def _compare(client: TestClient, auth: dict, site: int, pair: DsmPairPaths) -> dict:
    from tests.api_helpers import run_job_inline, upload_dsm

    pre = upload_dsm(client, auth, site, pair.pre, "2026-06-01T10:00:00Z")
    post = upload_dsm(client, auth, site, pair.post, "2026-07-01T10:00:00Z")
    created = client.post(
        f"/api/v1/sites/{site}/comparisons",
        json={"pre_survey_id": pre["id"], "post_survey_id": post["id"], "method": "threshold"},
        headers=auth,
    ).json()
    run_job_inline(created["job"]["id"])
    return created


def _deliveries(client: TestClient, auth: dict, site: int) -> list[dict]:
    return client.get(f"/api/v1/sites/{site}/deliveries", headers=auth).json()


def _attempt(app: FastAPI, delivery_id: int):
    return attempt_delivery(
        delivery_id, app.state.sessionmaker, app.state.storage, app.state.settings
    )


def test_signed_webhook_is_retried_until_delivered_and_every_attempt_logged(
    alert_app: FastAPI, client: TestClient, auth: dict, alert_pair: DsmPairPaths
) -> None:
    with WebhookReceiver(statuses=[500, 503]) as receiver:
        site, hook = _site_with_webhook(client, auth, receiver.url, min_area_m2=100)
        created = _compare(client, auth, site, alert_pair)
        [delivery] = _deliveries(client, auth, site)
        assert delivery["event"] == "landslides_detected" and delivery["status"] == "pending"

        outcomes = [_attempt(alert_app, delivery["id"]) for _ in range(3)]
        assert [o.status_code for o in outcomes] == [500, 503, 200]
        assert [o.retry_in_s for o in outcomes] == [pytest.approx(0.3), pytest.approx(0.6), None]
        assert _attempt(alert_app, delivery["id"]).retry_in_s is None  # delivered: no 4th call

    assert len(receiver.requests) == 3
    headers, body, _ = receiver.requests[-1]
    assert verify_signature(
        hook["secret"], headers[TIMESTAMP_HEADER], body, headers[SIGNATURE_HEADER]
    )
    assert not verify_signature(
        "whsec_other", headers[TIMESTAMP_HEADER], body, headers[SIGNATURE_HEADER]
    )
    assert not verify_signature(
        hook["secret"], headers[TIMESTAMP_HEADER], body + b" ", headers[SIGNATURE_HEADER]
    )
    later = int(headers[TIMESTAMP_HEADER]) + 3600
    assert not verify_signature(
        hook["secret"], headers[TIMESTAMP_HEADER], body, headers[SIGNATURE_HEADER], now=later
    )
    payload = json.loads(body)
    assert payload["event"] == "landslides_detected"
    assert payload["comparison"]["id"] == created["comparison"]["id"]
    [detection] = payload["detections"]
    assert detection["area_m2"] > 100 and 46 < detection["centroid"]["lat"] < 47
    assert payload["links"]["comparison"].startswith("https://slidewatch.example/api/v1/")

    [logged] = _deliveries(client, auth, site)
    assert logged["status"] == "delivered" and logged["attempts"] == 3
    assert [(a["attempt"], a["status_code"]) for a in logged["attempt_log"]] == [
        (1, 500),
        (2, 503),
        (3, 200),
    ]
    assert logged["attempt_log"][0]["error"] == "HTTP 500 Internal Server Error"
    # What the receiver wrote back is its own: never kept in the log members read.
    assert "t0p" not in json.dumps(logged) and "10.0.0.5" not in json.dumps(logged)
    assert "whsec" not in json.dumps(
        client.get(f"/api/v1/sites/{site}/webhooks", headers=auth).json()
    )


def test_delivery_gives_up_after_the_last_attempt(
    alert_app: FastAPI, client: TestClient, auth: dict, alert_pair: DsmPairPaths
) -> None:
    with WebhookReceiver(statuses=[500, 500, 500, 500]) as receiver:
        site, _ = _site_with_webhook(client, auth, receiver.url)
        _compare(client, auth, site, alert_pair)
        [delivery] = _deliveries(client, auth, site)
        outcomes = [_attempt(alert_app, delivery["id"]) for _ in range(4)]
    assert [o.status_code for o in outcomes] == [500, 500, 500, None]
    [logged] = _deliveries(client, auth, site)
    assert logged["status"] == "failed" and logged["attempts"] == 3
    assert logged["last_error"].startswith("gave up after 3 attempts")


def test_detections_below_the_thresholds_do_not_alert(
    client: TestClient, auth: dict, alert_pair: DsmPairPaths
) -> None:
    site, _ = _site_with_webhook(
        client, auth, "http://127.0.0.1:9/hook", min_area_m2=100, min_score=0.5, min_volume_m3=1e6
    )
    _compare(client, auth, site, alert_pair)
    assert _deliveries(client, auth, site) == []


def test_emails_reach_smtp_and_job_failures_alert_once(
    alert_app: FastAPI, client: TestClient, auth: dict, mailbox: MailReceiver, alert_pair
) -> None:
    site, _ = _site_with_webhook(
        client,
        auth,
        "http://127.0.0.1:9/hook",
        email_recipients=["geo@town.example", "duty@town.example"],
    )
    ids = finished_comparison(client, auth, alert_pair, name="second")
    assert ids["site"] != site
    created = _compare(client, auth, site, alert_pair)
    emails = [d for d in _deliveries(client, auth, site) if d["channel"] == "email"]
    assert [d["event"] for d in emails] == ["landslides_detected"]
    assert _attempt(alert_app, emails[0]["id"]).delivered
    [message] = mailbox.messages
    assert message["To"] == "geo@town.example, duty@town.example"
    assert message["Subject"] == (
        f"[slidewatch] watched: 1 landslide detected (comparison {created['comparison']['id']})"
    )
    text = message.get_payload(decode=True).decode()
    assert "m²" in text and "max |Δh|" in text

    # A job that fails for good alerts by webhook and e-mail, once however often it is told.
    job = client.post(
        f"/api/v1/sites/{site}/comparisons",
        json={"pre_survey_id": created["comparison"]["pre_survey_id"],
              "post_survey_id": created["comparison"]["post_survey_id"],
              "method": "threshold"},
        headers=auth,
    ).json()["job"]  # fmt: skip
    fail_job(job_context(), job["id"], "align", "the disk is full")
    failures = [d for d in _deliveries(client, auth, site) if d["event"] == "job_failed"]
    assert sorted(d["channel"] for d in failures) == ["email", "webhook"]
    email = next(d for d in failures if d["channel"] == "email")
    assert _attempt(alert_app, email["id"]).delivered
    assert "the disk is full" in mailbox.messages[-1].get_payload(decode=True).decode()


def test_unreachable_smtp_is_a_logged_failed_attempt(
    alert_app: FastAPI, client: TestClient, auth: dict, alert_pair: DsmPairPaths, mailbox
) -> None:
    site, _ = _site_with_webhook(
        client, auth, "http://127.0.0.1:9/hook", email_recipients=["a@b.example"]
    )
    _compare(client, auth, site, alert_pair)
    email = next(d for d in _deliveries(client, auth, site) if d["channel"] == "email")
    mailbox.stop()
    started = time.monotonic()
    outcome = _attempt(alert_app, email["id"])
    assert not outcome.delivered and outcome.retry_in_s == pytest.approx(0.3)
    assert time.monotonic() - started < 10
    logged = next(d for d in _deliveries(client, auth, site) if d["id"] == email["id"])
    assert logged["status"] == "retrying" and "Connection" in logged["attempt_log"][0]["error"]


@pytest.mark.parametrize(
    ("path", "body", "message"),
    [
        ("webhooks", {"url": "ftp://x.example/hook"}, "is not an http(s) URL"),
        ("webhooks", {"url": "https://x.example", "events": ["quake"]}, "unknown events"),
        ("webhooks", {"url": "https://x.example", "events": []}, "at least one event"),
        ("alerts", {"email_recipients": ["nobody"]}, "is not an e-mail address"),
        ("alerts", {"min_score": 2}, "less than or equal to 1"),
    ],
)
def test_bad_alert_settings_are_refused(
    client: TestClient, auth: dict, path: str, body: dict, message: str
) -> None:
    site = client.post("/api/v1/sites", json={"name": "s"}, headers=auth).json()["id"]
    method = client.put if path == "alerts" else client.post
    response = method(f"/api/v1/sites/{site}/{path}", json=body, headers=auth)
    assert response.status_code == 422
    assert message in json.dumps(response.json())
