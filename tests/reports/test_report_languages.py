"""Reports and their e-mails in the site's language or the one asked for: a Japanese
report of a real comparison has the Japanese headings, Japanese times and the same
landslides, labels and numbers as the English one; its PDF embeds a Japanese font."""

import email.header
import io
import os
import re
import subprocess
from pathlib import Path

from fastapi import FastAPI
from fastapi.testclient import TestClient
from pypdf import PdfReader

from backend.services.alerts import attempt_delivery
from tests.monitoring_helpers import MailReceiver, finished_comparison
from tests.reports.test_reports import _build, pdf_text
from worker.simulator.dsm_pair import DsmPairPaths

JAPANESE_HEADINGS = (
    "地すべり監視報告書：東斜面",
    "検出した地すべり",
    "前回の報告からの変化",
    "処理の記録",
    "解析パラメータ",
    "時刻はすべて Asia/Tokyo で表示しています。",
)
JAPANESE_COLUMNS = ("番号", "面積 (m²)", "減少量 (m³)", "増加量 (m³)", "最大 |Δh| (m)")


def _table_rows(html: str) -> list[list[str]]:
    """The landslide table's rows of a report's HTML (cells of right-aligned numbers)."""
    table = html.split("<table>")[1]
    rows = re.findall(r"<tr>((?:<td>[^<]*</td>)+)</tr>", table)
    return [re.findall(r"<td>([^<]*)</td>", row) for row in rows]


def test_a_japanese_report_matches_the_english_one_of_the_same_comparison(
    report_app: FastAPI,
    client: TestClient,
    auth: dict,
    report_pair: DsmPairPaths,
    mailbox: MailReceiver,
) -> None:
    ids = finished_comparison(client, auth, report_pair, name="東斜面")
    site = ids["site"]
    changed = client.patch(
        f"/api/v1/sites/{site}",
        json={"language": "ja", "timezone": "Asia/Tokyo"},
        headers=auth,
    )
    assert changed.status_code == 200 and changed.json()["language"] == "ja"
    put = client.put(
        f"/api/v1/sites/{site}/alerts", json={"email_recipients": ["bosai@city.example"]},
        headers=auth,
    )  # fmt: skip
    assert put.status_code == 200, put.text
    features = client.get(
        f"/api/v1/sites/{site}/comparisons/{ids['comparison']}/detections", headers=auth
    ).json()["features"]
    labels = [f["properties"]["label"] for f in features]
    assert labels == list(range(1, len(features) + 1)) and labels

    japanese = _build(report_app, client, auth, site)  # the site's language
    english = _build(report_app, client, auth, site, language="en")  # the user's
    assert japanese["status"] == english["status"] == "succeeded", japanese["error"]
    assert (japanese["language"], english["language"]) == ("ja", "en")

    text = pdf_text(client.get(japanese["pdf_url"], headers=auth).content)
    for heading in JAPANESE_HEADINGS + JAPANESE_COLUMNS:
        assert heading in text, heading
    # The surveys were captured at 10:00 UTC: 19:00 in Tokyo, written the Japanese way.
    assert "前時期：測量" in text and "2026年6月1日 19:00 JST" in text
    assert "2026年7月1日 19:00 JST" in text and "UTC" not in text
    assert f"地すべりを {len(labels)} 箇所検出しました。" in text
    assert "Landslide" not in text and "This is the first report" not in text
    english_text = pdf_text(client.get(english["pdf_url"], headers=auth).content)
    assert "Landslide monitoring report: 東斜面" in english_text
    assert "2026-06-01 19:00 JST" in english_text
    for feature in features:
        row = f"\n{feature['properties']['label']}\n{feature['properties']['area_m2']:,.1f}\n"
        assert row in text and row in english_text  # one table row, in both

    # The Japanese text is drawn with an embedded Japanese TrueType font (no empty boxes).
    pdf = client.get(japanese["pdf_url"], headers=auth).content
    page = PdfReader(io.BytesIO(pdf)).pages[0]
    fonts = {
        str(f.get_object()["/BaseFont"]).split("+")[-1]: f.get_object()
        for f in page["/Resources"]["/Font"].values()
    }
    assert {"DejaVuSans", "DejaVuSans-Bold", "IPAexGothic"} <= set(fonts)
    assert "/FontFile2" in fonts["IPAexGothic"]["/FontDescriptor"]
    _docs_image(pdf, "report-page1-ja")

    html = client.get(japanese["html_url"], headers=auth).text
    assert '<html lang="ja">' in html
    for heading in (*JAPANESE_HEADINGS, "概要", "標高差分図", *JAPANESE_COLUMNS):
        assert heading in html, heading
    english_html = client.get(english["html_url"], headers=auth).text
    assert '<html lang="en">' in english_html and "Change since the previous report" in english_html
    # Same landslides, same labels 1…n, same numbers, in the same order.
    rows = _table_rows(html)
    assert rows == _table_rows(english_html)
    assert [int(row[0]) for row in rows] == labels

    # The report's e-mail is in the site's language, with the PDF attached.
    emails = [
        d
        for d in client.get(f"/api/v1/sites/{site}/deliveries", headers=auth).json()
        if d["channel"] == "email" and d["event"] == "report_ready"
    ]
    first = next(d for d in emails if d["payload"]["report"]["id"] == japanese["id"])
    outcome = attempt_delivery(
        first["id"],
        report_app.state.sessionmaker,
        report_app.state.storage,
        report_app.state.settings,
    )
    assert outcome.delivered, outcome.error
    [message] = mailbox.messages
    subject = str(email.header.make_header(email.header.decode_header(message["Subject"])))
    assert subject == f"[slidewatch] 東斜面：報告書 {japanese['id']}"
    body_text = next(
        part.get_payload(decode=True).decode()
        for part in message.walk()
        if part.get_content_type() == "text/plain"
    )
    assert f"報告書 {japanese['id']} ができました（地すべり {len(labels)} 箇所）" in body_text
    assert "現場：東斜面" in body_text and "日時：2026年" in body_text and "JST" in body_text


def _docs_image(pdf: bytes, name: str) -> None:
    """The PDF's first page as a PNG into the docs, when SLIDEWATCH_DOCS_SCREENSHOTS asks."""
    docs = os.environ.get("SLIDEWATCH_DOCS_SCREENSHOTS")
    if not docs:
        return
    source = Path(docs) / f"{name}.pdf"
    source.write_bytes(pdf)
    command = ["pdftoppm", "-png", "-r", "70", "-singlefile", "-f", "1", "-l", "1"]
    subprocess.run([*command, str(source), str(Path(docs) / name)], check=True)
    source.unlink()


def test_the_language_asked_for_is_checked(
    client: TestClient, auth: dict, report_pair: DsmPairPaths
) -> None:
    languages = client.get("/api/v1/languages", headers=auth)
    assert languages.status_code == 200
    assert languages.json() == [
        {"code": "en", "name": "English", "default": True},
        {"code": "ja", "name": "日本語", "default": False},
    ]
    made = client.post("/api/v1/sites", json={"name": "斜面A"}, headers=auth)
    assert made.status_code == 201 and made.json()["language"] == "en"
    site = made.json()["id"]
    for response in (
        client.post("/api/v1/sites", json={"name": "b", "language": "fr"}, headers=auth),
        client.patch(f"/api/v1/sites/{site}", json={"language": "JA"}, headers=auth),
        client.post(f"/api/v1/sites/{site}/reports", json={"language": "de"}, headers=auth),
    ):
        assert response.status_code == 422
        [problem] = response.json()["detail"]
        assert problem["loc"][-1] == "language"
        assert "unknown language" in problem["msg"] and "use one of en, ja" in problem["msg"]
    cleared = client.patch(f"/api/v1/sites/{site}", json={"language": None}, headers=auth)
    assert cleared.status_code == 422 and "cannot be null" in cleared.text
    query = client.post(f"/api/v1/sites/{site}/reports?lang=xx", json={}, headers=auth)
    assert query.status_code == 422
    assert query.json()["detail"] == "unknown language 'xx': use one of en, ja"
    assert client.get(f"/api/v1/sites/{site}", headers=auth).json()["language"] == "en"
