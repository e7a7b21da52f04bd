"""Alert e-mails in the site's language: a Japanese site's landslide alert has a Japanese
subject and body, its times in the site's zone and its numbers as the API gives them."""

import email.header

from fastapi import FastAPI
from fastapi.testclient import TestClient

from backend.services.alerts import attempt_delivery
from tests.alerts.test_alerts import _compare, _deliveries
from tests.monitoring_helpers import MailReceiver
from worker.simulator.dsm_pair import DsmPairPaths


def _subject(message) -> str:
    return str(email.header.make_header(email.header.decode_header(message["Subject"])))


def _body(message) -> str:
    return message.get_payload(decode=True).decode()


def test_a_japanese_site_is_alerted_in_japanese(
    alert_app: FastAPI,
    client: TestClient,
    auth: dict,
    mailbox: MailReceiver,
    alert_pair: DsmPairPaths,
) -> None:
    made = client.post(
        "/api/v1/sites",
        json={"name": "裏山", "language": "ja", "timezone": "Asia/Tokyo"},
        headers=auth,
    )
    assert made.status_code == 201 and made.json()["language"] == "ja", made.text
    site = made.json()["id"]
    put = client.put(
        f"/api/v1/sites/{site}/alerts", json={"email_recipients": ["bosai@city.example"]},
        headers=auth,
    )  # fmt: skip
    assert put.status_code == 200, put.text
    created = _compare(client, auth, site, alert_pair)
    comparison = created["comparison"]["id"]
    [delivery] = [d for d in _deliveries(client, auth, site) if d["channel"] == "email"]
    outcome = attempt_delivery(
        delivery["id"], alert_app.state.sessionmaker, alert_app.state.storage,
        alert_app.state.settings,
    )  # fmt: skip
    assert outcome.delivered, outcome.error

    [message] = mailbox.messages
    assert _subject(message) == f"[slidewatch] 裏山：地すべり 1 箇所を検出（比較 {comparison}）"
    body = _body(message)
    [landslide] = client.get(
        f"/api/v1/sites/{site}/comparisons/{comparison}/detections", headers=auth
    ).json()["features"]
    found = landslide["properties"]
    assert body.startswith(f"現場：裏山（ID {site}）\n日時：20")
    assert " JST\n" in body and "UTC" not in body
    assert f"比較 {comparison} で次の地すべりを検出しました。" in body
    assert (
        f"  検出 1：面積 {found['area_m2']:,.1f}m²、減少量 {found['volume_loss_m3']:,.1f}m³、"
        f"増加量 {found['volume_gain_m3']:,.1f}m³、最大 |Δh| {found['max_abs_dh_m']:.2f}m"
    ) in body
    assert "\n比較：https://slidewatch.example/api/v1/" in body

    # The test e-mail too; the same site in English is alerted in English again.
    test = client.post(f"/api/v1/sites/{site}/alerts/test-email", headers=auth)
    assert test.status_code == 202, test.text
    assert attempt_delivery(
        test.json()["id"], alert_app.state.sessionmaker, alert_app.state.storage,
        alert_app.state.settings,
    ).delivered  # fmt: skip
    assert _subject(mailbox.messages[-1]) == "[slidewatch] 裏山：テストメール"
    assert "この宛先には現場のアラートが届きます。" in _body(mailbox.messages[-1])
    client.patch(f"/api/v1/sites/{site}", json={"language": "en"}, headers=auth)
    test = client.post(f"/api/v1/sites/{site}/alerts/test-email", headers=auth)
    attempt_delivery(
        test.json()["id"], alert_app.state.sessionmaker, alert_app.state.storage,
        alert_app.state.settings,
    )  # fmt: skip
    assert _subject(mailbox.messages[-1]) == "[slidewatch] 裏山: test e-mail"
    assert "A test from slidewatch" in _body(mailbox.messages[-1])
