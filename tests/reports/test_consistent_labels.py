"""One label per detection (1…n in its comparison) in the API's GeoJSON, every export
format and the report; the report's times in the site's time zone; schedule previews."""

import io
import zipfile
from datetime import UTC, datetime

import pyogrio
from fastapi import FastAPI
from fastapi.testclient import TestClient

from tests.api_helpers import request_comparison, run_job_inline
from tests.monitoring_helpers import finished_comparison
from tests.reports.test_reports import _build, pdf_text
from worker.simulator.dsm_pair import DsmPairPaths


def _labels_of_file(content: bytes, suffix: str, tmp_path) -> list[int]:
    tmp_path.mkdir(parents=True)
    path = tmp_path / f"detections.{suffix}"
    if suffix == "shp.zip":
        with zipfile.ZipFile(io.BytesIO(content)) as bundle:
            names = bundle.namelist()
            assert {n.rsplit(".", 1)[1] for n in names} >= {"shp", "shx", "dbf", "prj"}
            bundle.extractall(tmp_path)
        path = tmp_path / next(n for n in names if n.endswith(".shp"))
    else:
        path.write_bytes(content)
    table = pyogrio.read_dataframe(path)
    return [int(v) for v in table["label"]]


def test_a_detection_has_one_label_everywhere_and_times_are_the_sites(
    report_app: FastAPI, client: TestClient, auth: dict, report_pair: DsmPairPaths, tmp_path
) -> None:
    ids = finished_comparison(client, auth, report_pair, name="Labels")
    site = ids["site"]
    assert (
        client.patch(f"/api/v1/sites/{site}", json={"timezone": "Asia/Tokyo"}, headers=auth)
    ).status_code == 200
    # A second run of the same pair: its detections have new database ids, labels from 1.
    again = request_comparison(
        client, auth, site, ids["pre"], ids["post"], "threshold", run_again=True
    ).json()
    run_job_inline(again["job"]["id"])
    comparison = again["comparison"]["id"]
    base = f"/api/v1/sites/{site}/comparisons/{comparison}/detections"
    features = client.get(base, headers=auth).json()["features"]
    labels = [f["properties"]["label"] for f in features]
    assert labels == list(range(1, len(features) + 1)) and labels
    assert [f["id"] for f in features] != labels  # the label is not the database id
    ogc = client.get(
        "/ogc/collections/detections/items", params={"comparison_id": comparison}, headers=auth
    ).json()
    assert [f["properties"]["label"] for f in ogc["features"]] == labels

    for file_format, suffix, media_type in (
        ("gpkg", "gpkg", "application/geopackage+sqlite3"),
        ("kml", "kml", "application/vnd.google-earth.kml+xml"),
        ("shp", "shp.zip", "application/zip"),
    ):
        answer = client.get(f"{base}/{file_format}", headers=auth)
        assert answer.status_code == 200, answer.text
        assert answer.headers["content-type"].startswith(media_type)
        assert (
            f"comparison-{comparison}-detections.{suffix}" in answer.headers["content-disposition"]
        )
        assert _labels_of_file(answer.content, suffix, tmp_path / file_format) == labels
    assert client.get(f"{base}/xlsx", headers=auth).status_code == 422

    report = _build(report_app, client, auth, site, comparison_id=comparison)
    assert report["status"] == "succeeded", report["error"]
    text = pdf_text(client.get(report["pdf_url"], headers=auth).content)
    for feature in features:
        area = f"{feature['properties']['area_m2']:,.1f}"
        assert f"\n{feature['properties']['label']}\n{area}\n" in text  # a table row
    assert "Times in Asia/Tokyo." in text
    # The surveys were captured at 10:00 UTC: 19:00 in Tokyo, named as such.
    assert "2026-06-01 19:00 JST" in text and "UTC)" not in text


def test_the_next_five_runs_of_a_cron_expression(client: TestClient, auth: dict) -> None:
    site = client.post("/api/v1/sites", json={"name": "cron"}, headers=auth).json()["id"]
    preview = client.get(
        f"/api/v1/sites/{site}/schedules/preview",
        params={"cron": "0 6 * * 1", "timezone": "Asia/Tokyo"},
        headers=auth,
    )
    assert preview.status_code == 200, preview.text
    runs = [datetime.fromisoformat(t) for t in preview.json()["next_runs"]]
    assert len(runs) == 5 and runs == sorted(runs) and runs[0] > datetime.now(UTC)
    # Mondays 06:00 in Tokyo are Sundays 21:00 UTC, a week apart.
    assert all(r.astimezone(UTC).weekday() == 6 and r.astimezone(UTC).hour == 21 for r in runs)
    bad = client.get(
        f"/api/v1/sites/{site}/schedules/preview", params={"cron": "0 25 * * *"}, headers=auth
    )
    assert bad.status_code == 422 and "five fields" in bad.json()["detail"]
