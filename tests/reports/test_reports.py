"""Reports on demand: PDF with embedded fonts and the right numbers, HTML, the change
since the previous report, delivery by e-mail (PDF attached) and webhook. A report is
built by a job, run here in this process exactly as a worker runs it."""

import io

import pytest
from fastapi import FastAPI
from fastapi.testclient import TestClient
from pypdf import PdfReader

from backend.services.alerts import attempt_delivery
from tests.api_helpers import run_job_inline
from tests.monitoring_helpers import MailReceiver, WebhookReceiver, finished_comparison
from worker.simulator.dsm_pair import DsmPairPaths


def _build(app: FastAPI, client: TestClient, auth: dict, site: int, **body) -> dict:
    created = client.post(f"/api/v1/sites/{site}/reports", json=body, headers=auth)
    assert created.status_code == 202, created.text
    assert created.json()["status"] == "queued" and created.json()["job_id"] is not None
    run_job_inline(created.json()["job_id"], "build")
    return client.get(f"/api/v1/sites/{site}/reports/{created.json()['id']}", headers=auth).json()


def pdf_text(content: bytes) -> str:
    return "\n".join(page.extract_text() for page in PdfReader(io.BytesIO(content)).pages)


def test_report_pdf_and_html_hold_the_comparison_numbers(
    report_app: FastAPI, client: TestClient, auth: dict, report_pair: DsmPairPaths
) -> None:
    ids = finished_comparison(client, auth, report_pair, name="East flank")
    detections = client.get(
        f"/api/v1/sites/{ids['site']}/comparisons/{ids['comparison']}/detections", headers=auth
    ).json()["features"]
    [landslide] = [d["properties"] for d in detections]
    report = _build(report_app, client, auth, ids["site"])
    assert report["status"] == "succeeded", report["error"]
    assert report["summary"]["detections"] == 1
    assert report["summary"]["comparison_id"] == ids["comparison"]

    pdf = client.get(report["pdf_url"], headers=auth)
    assert pdf.status_code == 200 and pdf.headers["content-type"] == "application/pdf"
    text = pdf_text(pdf.content)
    assert "Landslide monitoring report: East flank" in text
    assert f"{landslide['area_m2']:,.1f}" in text
    assert f"{landslide['volume_loss_m3']:,.1f}" in text
    assert f"{landslide['volume_gain_m3']:,.1f}" in text
    assert f"{landslide['max_abs_dh_m']:.2f}" in text
    assert "max |Δh| (m)" in text and "Loss (m³)" in text and "Area (m²)" in text
    assert "This is the first report of the site." in text
    assert "coregister.shift_east_m" in text and "Model version: slidewatch" in text
    page = PdfReader(io.BytesIO(pdf.content)).pages[0]
    fonts = [f.get_object() for f in page["/Resources"]["/Font"].values()]
    dejavu = [f for f in fonts if "DejaVuSans" in str(f["/BaseFont"])]
    assert len(dejavu) == 2  # regular and bold, subset and embedded
    for font in dejavu:
        assert font["/Subtype"] == "/TrueType" and "/FontFile2" in font["/FontDescriptor"]

    html = client.get(report["html_url"], headers=auth)
    assert html.headers["content-type"].startswith("text/html")
    assert f"{landslide['area_m2']:,.1f}" in html.text and "data:image/png;base64," in html.text

    again = _build(report_app, client, auth, ids["site"])
    text = pdf_text(client.get(again["pdf_url"], headers=auth).content)
    assert f"No new comparison since report {report['id']}" in text
    listed = client.get(f"/api/v1/sites/{ids['site']}/reports", headers=auth).json()
    assert [r["id"] for r in listed] == [again["id"], report["id"]]


def test_report_is_delivered_by_email_with_the_pdf_and_by_webhook(
    report_app: FastAPI,
    client: TestClient,
    auth: dict,
    report_pair: DsmPairPaths,
    mailbox: MailReceiver,
) -> None:
    ids = finished_comparison(client, auth, report_pair)
    site = ids["site"]
    client.put(
        f"/api/v1/sites/{site}/alerts", json={"email_recipients": ["a@b.example"]}, headers=auth
    )
    with WebhookReceiver() as receiver:
        client.post(
            f"/api/v1/sites/{site}/webhooks",
            json={"url": receiver.url, "events": ["report_ready"]},
            headers=auth,
        )
        report = _build(report_app, client, auth, site)
        deliveries = client.get(f"/api/v1/sites/{site}/deliveries", headers=auth).json()
        assert sorted(d["channel"] for d in deliveries) == ["email", "webhook"]
        for delivery in deliveries:
            outcome = attempt_delivery(
                delivery["id"],
                report_app.state.sessionmaker,
                report_app.state.storage,
                report_app.state.settings,
            )
            assert outcome.delivered, outcome.error
    assert receiver.requests[0][1].startswith(b'{"event":"report_ready"')
    [message] = mailbox.messages
    [attachment] = [part for part in message.walk() if part.get_filename()]
    assert attachment.get_filename() == f"slidewatch-report-{report['id']}.pdf"
    assert (
        attachment.get_payload(decode=True) == client.get(report["pdf_url"], headers=auth).content
    )


def test_report_without_a_finished_comparison_is_refused(client: TestClient, auth: dict) -> None:
    site = client.post("/api/v1/sites", json={"name": "empty"}, headers=auth).json()["id"]
    response = client.post(f"/api/v1/sites/{site}/reports", json={}, headers=auth)
    assert response.status_code == 409
    assert "no finished comparison" in response.json()["detail"]
    response = client.post(f"/api/v1/sites/{site}/reports", json={"comparison_id": 7}, headers=auth)
    assert response.status_code == 409 and "comparison 7 not found" in response.json()["detail"]
    assert client.get(f"/api/v1/sites/{site}/reports/1/pdf", headers=auth).status_code == 404


@pytest.mark.parametrize(
    ("body", "message"),
    [
        ({"cron": "every monday"}, "invalid cron expression"),
        ({"cron": "0 6 * * 1 2026"}, "invalid cron expression"),
        ({"cron": "0 6 * * 1", "timezone": "Mars/Olympus"}, "unknown time zone"),
        ({"cron": "0 6 * * 1", "next_run_at": "2026-06-01T06:00:00"}, "time zone offset"),
    ],
)
def test_bad_schedules_are_refused(client: TestClient, auth: dict, body: dict, message: str):
    site = client.post("/api/v1/sites", json={"name": "s"}, headers=auth).json()["id"]
    response = client.post(f"/api/v1/sites/{site}/schedules", json=body, headers=auth)
    assert response.status_code == 422
    assert message in response.json()["detail"]
