"""Comparisons: validation, queuing, job progress, detections and products over the API."""

import json

import pytest
from fastapi import FastAPI
from fastapi.testclient import TestClient
from shapely.geometry import shape
from shapely.geometry.polygon import orient
from sqlalchemy import create_engine, text

from backend.config import Settings
from backend.db.models import Survey
from tests.api_helpers import run_job_inline, upload_dsm
from worker.pipeline.comparison import default_method, stages_for
from worker.simulator.dsm_pair import DsmPairPaths, make_dsm_pair, write_dsm_pair


@pytest.fixture
def embedded_settings(embedded_settings: Settings) -> Settings:
    """As deployed, a ready survey's tiles are queued to be rendered ahead (no worker runs
    here to render them; tests/conftest.py turns it off for the suite's workers)."""
    embedded_settings.tile_prerender_max_tiles = Settings.model_fields[
        "tile_prerender_max_tiles"
    ].default
    return embedded_settings


@pytest.fixture
def site_id(client: TestClient, auth: dict) -> int:
    return client.post("/api/v1/sites", json={"name": "slope"}, headers=auth).json()["id"]


@pytest.fixture
def surveys(client: TestClient, auth: dict, site_id: int, dsm_pair_files: DsmPairPaths):
    pre = upload_dsm(client, auth, site_id, dsm_pair_files.pre, "2026-06-01T10:00:00Z")
    post = upload_dsm(client, auth, site_id, dsm_pair_files.post, "2026-07-01T10:00:00Z")
    return pre["id"], post["id"]


def create(client: TestClient, auth: dict, site_id: int, pre: int, post: int, **extra):
    return client.post(
        f"/api/v1/sites/{site_id}/comparisons",
        json={"pre_survey_id": pre, "post_survey_id": post, **extra},
        headers=auth,
    )


def broker_messages(app: FastAPI) -> list[dict]:
    engine = create_engine(app.state.settings.resolved_broker_url.removeprefix("sqla+"))
    with engine.connect() as connection:
        rows = connection.execute(text("SELECT payload FROM kombu_message")).all()
    engine.dispose()
    return [json.loads(row[0]) for row in rows]


def test_creating_a_comparison_queues_its_first_stage(
    client: TestClient, app: FastAPI, auth: dict, site_id: int, surveys: tuple[int, int]
) -> None:
    response = create(client, auth, site_id, *surveys)
    assert response.status_code == 202, response.text
    body = response.json()
    assert body["comparison"]["status"] == "queued"
    # No method given: the library's default, the one the CLI and the page use too.
    assert body["comparison"]["method"] == default_method()
    job = body["job"]
    assert job["state"] == "queued"
    assert [s["stage"] for s in job["stages"]] == list(stages_for(default_method()))
    assert all(s["state"] == "pending" and s["progress"] == 0 for s in job["stages"])
    messages = broker_messages(app)
    stages = [m for m in messages if m["headers"]["task"] == "slidewatch.run_stage"]
    assert len(stages) == 1
    assert stages[0]["headers"]["argsrepr"] == f"[{job['id']}, 'align']"
    # Besides: each survey's map tiles, to be rendered ahead since its upload.
    others = [m["headers"] for m in messages if m not in stages]
    assert {(h["task"], h["argsrepr"]) for h in others} == {
        ("slidewatch.prerender_tiles", f"['surveys', {survey}, 0]") for survey in surveys
    }


def test_finished_comparison_serves_detections_and_products(
    client: TestClient, auth: dict, site_id: int, surveys: tuple[int, int]
) -> None:
    created = create(client, auth, site_id, *surveys, method="threshold").json()
    comparison_id, job_id = created["comparison"]["id"], created["job"]["id"]
    run_job_inline(job_id)

    job = client.get(f"/api/v1/sites/{site_id}/jobs/{job_id}", headers=auth).json()
    assert job["state"] == "succeeded"
    assert job["progress"] == 1.0
    for stage in job["stages"]:
        assert stage["state"] == "succeeded"
        assert stage["attempts"] == 1
        assert stage["result"]["wall_seconds"] >= 0

    comparison = client.get(
        f"/api/v1/sites/{site_id}/comparisons/{comparison_id}", headers=auth
    ).json()
    assert comparison["status"] == "succeeded"
    assert comparison["job_id"] == job_id
    correction = job["stages"][1]["result"]  # undoes post's displacement of (1.3, -0.7) m
    assert correction["shift_east_m"] == pytest.approx(-1.3, abs=0.1)
    assert correction["shift_north_m"] == pytest.approx(0.7, abs=0.1)

    response = client.get(
        f"/api/v1/sites/{site_id}/comparisons/{comparison_id}/detections", headers=auth
    )
    assert response.status_code == 200
    assert response.headers["content-type"] == "application/geo+json"
    collection = response.json()
    assert collection["type"] == "FeatureCollection"
    assert "crs" not in collection
    assert len(collection["features"]) == 1
    feature = collection["features"][0]
    polygon = shape(feature["geometry"])
    assert polygon.is_valid
    assert orient(polygon, 1.0).equals_exact(polygon, 0)  # exterior ring counter-clockwise
    lon, lat = polygon.centroid.coords[0]
    assert 6 < lon < 12 and 0 < lat < 84
    props = feature["properties"]
    assert props["method"] == "threshold" and props["model_version"] is None
    assert props["area_m2"] > 0 and props["volume_loss_m3"] > 0 and props["volume_gain_m3"] > 0
    assert 0 <= props["score"] <= 1
    # The 95 % intervals and the LoD of the polygon are kept with the detection.
    uncertainty = props["uncertainty"]
    assert set(uncertainty) == {
        "area_m2_ci95",
        "volume_loss_m3_ci95",
        "volume_gain_m3_ci95",
        "lod_m",
    }
    for name in ("area_m2", "volume_loss_m3", "volume_gain_m3"):
        low, high = uncertainty[f"{name}_ci95"]
        assert 0 <= low <= props[name] <= high, (name, low, props[name], high)
    assert uncertainty["area_m2_ci95"][0] < uncertainty["area_m2_ci95"][1]
    assert uncertainty["lod_m"] > 0
    assert comparison["summary"]["detections"] == 1
    # The comparison says how it detected: method, the LoD applied, no model (threshold).
    difference = job["stages"][2]["result"]
    detection = comparison["detection"]
    assert detection == {
        "method": "threshold",
        "lod_m": difference["lod_m"],
        "lod_p10_m": difference["lod_p10_m"],
        "lod_p90_m": difference["lod_p90_m"],
        "error_model": difference["error_model"],
        "model": None,
    }
    assert 0 < detection["lod_p10_m"] <= detection["lod_m"] <= detection["lod_p90_m"]
    assert detection["error_model"] in ("heteroscedastic", "uniform")

    products = client.get(
        f"/api/v1/sites/{site_id}/comparisons/{comparison_id}/products", headers=auth
    ).json()
    assert {p["kind"] for p in products} == {
        "post_coregistered",
        "dh",
        "significance",
        "lod",
        "detections",
    }
    dh = next(p for p in products if p["kind"] == "dh")
    assert dh["crs"] == "EPSG:32632"
    assert client.get(dh["download_url"], headers=auth).content[:4] in (b"II*\x00", b"MM\x00*")
    lod = next(p for p in products if p["kind"] == "lod")  # a COG, like dh
    assert lod["crs"] == "EPSG:32632"
    assert lod["file"]["media_type"].endswith("profile=cloud-optimized")


@pytest.mark.parametrize(
    ("change", "status", "message"),
    [
        ({"method": "magic"}, 422, "unknown detection method 'magic'"),
        (
            {"method": "cnn", "parameters": {"cnn": {"model": "/etc/passwd"}}},
            422,
            "no registered detection model '/etc/passwd'",
        ),
        (
            {"method": "scored", "parameters": {"score": {"scorer": "/etc/passwd"}}},
            422,
            "cannot be set over the API",
        ),
        ({"post_survey_id": "pre"}, 422, "same survey"),
        ({"post_survey_id": 999}, 422, "post survey 999 does not exist"),
        ({"parameters": {"no_such_option": 1}}, 422, "invalid parameters"),
    ],
)
def test_bad_comparison_requests_are_refused(
    client: TestClient, auth: dict, site_id: int, surveys: tuple[int, int],
    change: dict, status: int, message: str,
) -> None:  # fmt: skip
    pre, post = surveys
    body = {"pre_survey_id": pre, "post_survey_id": post, **change}
    if body["post_survey_id"] == "pre":
        body["post_survey_id"] = pre
    response = client.post(f"/api/v1/sites/{site_id}/comparisons", json=body, headers=auth)
    assert response.status_code == status
    assert message in response.json()["detail"]
    assert client.get(f"/api/v1/sites/{site_id}/comparisons", headers=auth).json() == []
    assert client.get(f"/api/v1/sites/{site_id}/jobs", headers=auth).json() == []


def test_surveys_of_different_sites_cannot_be_compared(
    client: TestClient, auth: dict, site_id: int, surveys: tuple[int, int],
    dsm_pair_files: DsmPairPaths,
) -> None:  # fmt: skip
    other = client.post("/api/v1/sites", json={"name": "other"}, headers=auth).json()["id"]
    foreign = upload_dsm(client, auth, other, dsm_pair_files.post, "2026-07-01T10:00:00Z")
    response = create(client, auth, site_id, surveys[0], foreign["id"])
    assert response.status_code == 422
    assert "belongs to another site" in response.json()["detail"]


def test_surveys_that_do_not_overlap_cannot_be_compared(
    client: TestClient, auth: dict, site_id: int, tmp_path, surveys: tuple[int, int]
) -> None:
    far = make_dsm_pair(shape=(60, 60), pixel_size_m=1.0, seed=3, origin=(700000.0, 5200000.0))
    far_paths = write_dsm_pair(far, tmp_path)
    elsewhere = upload_dsm(client, auth, site_id, far_paths.pre, "2026-07-01T10:00:00Z")
    response = create(client, auth, site_id, surveys[0], elsewhere["id"])
    assert response.status_code == 422
    assert "do not overlap" in response.json()["detail"]


def test_comparison_of_another_site_is_not_served(
    client: TestClient, auth: dict, site_id: int, surveys: tuple[int, int]
) -> None:
    created = create(client, auth, site_id, *surveys).json()
    other = client.post("/api/v1/sites", json={"name": "other"}, headers=auth).json()["id"]
    cid, jid = created["comparison"]["id"], created["job"]["id"]
    for path in (
        f"/api/v1/sites/{other}/comparisons/{cid}",
        f"/api/v1/sites/{other}/comparisons/{cid}/detections",
        f"/api/v1/sites/{other}/comparisons/{cid}/products",
        f"/api/v1/sites/{other}/jobs/{jid}",
    ):
        response = client.get(path, headers=auth)
        assert response.status_code == 404, path
    assert client.post(f"/api/v1/sites/{other}/jobs/{jid}/retry", headers=auth).status_code == 404
    assert client.get(f"/api/v1/sites/{other}/jobs", headers=auth).json() == []


def test_survey_in_use_cannot_be_deleted_until_its_comparison_is(
    client: TestClient, auth: dict, site_id: int, surveys: tuple[int, int]
) -> None:
    created = create(client, auth, site_id, *surveys).json()
    response = client.delete(f"/api/v1/sites/{site_id}/surveys/{surveys[0]}", headers=auth)
    assert response.status_code == 409
    assert "used by comparisons" in response.json()["detail"]
    cid = created["comparison"]["id"]
    assert (
        client.delete(f"/api/v1/sites/{site_id}/comparisons/{cid}", headers=auth).status_code == 204
    )
    assert client.get(f"/api/v1/sites/{site_id}/jobs", headers=auth).json() == []
    assert (
        client.delete(f"/api/v1/sites/{site_id}/surveys/{surveys[0]}", headers=auth).status_code
        == 204
    )


def test_failed_job_reports_its_reason_and_can_be_retried(
    client: TestClient, app: FastAPI, auth: dict, site_id: int, surveys: tuple[int, int]
) -> None:
    created = create(client, auth, site_id, *surveys).json()
    job_id = created["job"]["id"]
    conflict = client.post(f"/api/v1/sites/{site_id}/jobs/{job_id}/retry", headers=auth)
    assert conflict.status_code == 409

    # The pre DSM's file gets damaged on disk (e.g. a failing drive).
    dsm_path = stored_dsm_path(app, surveys[0])
    kept = dsm_path.read_bytes()
    dsm_path.write_bytes(b"garbage")
    run_job_inline(job_id)
    job = client.get(f"/api/v1/sites/{site_id}/jobs/{job_id}", headers=auth).json()
    assert job["state"] == "failed"
    assert job["stages"][0]["state"] == "failed"
    assert job["error"].startswith("align: ")
    comparison = client.get(
        f"/api/v1/sites/{site_id}/comparisons/{created['comparison']['id']}", headers=auth
    ).json()
    assert comparison["status"] == "failed"
    assert comparison["error"] == job["error"]

    dsm_path.write_bytes(kept)
    retried = client.post(f"/api/v1/sites/{site_id}/jobs/{job_id}/retry", headers=auth)
    assert retried.status_code == 202
    assert retried.json()["state"] == "queued"
    run_job_inline(job_id)
    job = client.get(f"/api/v1/sites/{site_id}/jobs/{job_id}", headers=auth).json()
    assert job["state"] == "succeeded"
    assert job["stages"][0]["attempts"] == 2


def stored_dsm_path(app: FastAPI, survey_id: int):
    with app.state.sessionmaker() as session:
        survey = session.get(Survey, survey_id)
        dsm = next(p for p in survey.products if p.kind == "dsm")
        return app.state.storage.absolute(dsm.file.path)
