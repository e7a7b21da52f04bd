"""The detection methods over the API: GET /methods from the library's tables, one default
(the library's default_method(), the CLI's and the page's too), and a comparison created
without a method runs it and says how it detected (method, LoD, model)."""

import json
from pathlib import Path

import pytest
from fastapi import FastAPI
from fastapi.testclient import TestClient

from backend.db.models import Comparison, JobState
from tests.api_helpers import run_job_inline, upload_dsm
from worker.jobs.control import JobKindName, new_job
from worker.pipeline.comparison import ComparisonOptions, stages_for
from worker.pipeline.detection_methods import (
    default_method,
    detection_method,
    detection_methods,
    method_names,
)
from worker.pipeline.methods import scored as scored_method
from worker.pipeline.scorer import load_scorer, shipped_scorer_available
from worker.simulator.dsm_pair import DsmPairPaths


@pytest.fixture
def site_and_surveys(
    client: TestClient, auth: dict, dsm_pair_files: DsmPairPaths
) -> tuple[int, int, int]:
    site = client.post("/api/v1/sites", json={"name": "slope"}, headers=auth).json()["id"]
    pre = upload_dsm(client, auth, site, dsm_pair_files.pre, "2026-06-01T10:00:00Z")
    post = upload_dsm(client, auth, site, dsm_pair_files.post, "2026-07-01T10:00:00Z")
    return site, pre["id"], post["id"]


def test_methods_lists_the_three_with_the_library_default(client: TestClient, auth: dict) -> None:
    response = client.get("/api/v1/methods", headers=auth)
    assert response.status_code == 200, response.text
    methods = response.json()
    assert [m["name"] for m in methods] == list(method_names()) == ["threshold", "scored", "cnn"]
    for method in methods:
        assert method["summary"] == detection_method(method["name"]).summary
        assert method["stages"] == list(stages_for(method["name"]))
    assert [m["name"] for m in methods if m["default"]] == [default_method()]
    # The scored method is the default exactly when its scorer ships.
    assert default_method() == "threshold" and shipped_scorer_available()


@pytest.mark.parametrize("doc", ["README.md", "docs/detection.md", "docs/frontend.md"])
def test_the_docs_list_each_method_with_its_line(doc: str) -> None:
    text = (Path(__file__).resolve().parents[2] / doc).read_text()
    for method in detection_methods():
        assert f"`{method.name}`" in text and method.summary in text, (doc, method.name)
    default = default_method()
    assert f"`{default}` (the default" in text or f"`{default}` (default)" in text, doc


def test_methods_need_a_token(client: TestClient) -> None:
    assert client.get("/api/v1/methods").status_code == 401


def test_a_comparison_without_a_method_runs_the_default_and_says_how(
    client: TestClient, auth: dict, site_and_surveys: tuple[int, int, int]
) -> None:
    site, pre, post = site_and_surveys
    default = next(m for m in client.get("/api/v1/methods", headers=auth).json() if m["default"])
    created = client.post(
        f"/api/v1/sites/{site}/comparisons",
        json={"pre_survey_id": pre, "post_survey_id": post},
        headers=auth,
    )
    assert created.status_code == 202, created.text
    queued = created.json()
    assert queued["comparison"]["method"] == default["name"]
    assert [s["stage"] for s in queued["job"]["stages"]] == default["stages"]
    # Nothing has run yet: the method is known, the LoD not.
    assert queued["comparison"]["detection"]["method"] == default["name"]
    assert queued["comparison"]["detection"]["lod_m"] is None

    run_job_inline(queued["job"]["id"])
    cid = queued["comparison"]["id"]
    comparison = client.get(f"/api/v1/sites/{site}/comparisons/{cid}", headers=auth).json()
    assert comparison["status"] == "succeeded", comparison
    detection = comparison["detection"]
    difference = comparison["summary"]["stages"]["difference"]
    assert detection["method"] == default["name"]
    assert detection["lod_m"] == difference["lod_m"] > 0
    assert detection["lod_p10_m"] <= detection["lod_m"] <= detection["lod_p90_m"]
    assert detection["error_model"] == difference["error_model"]
    # The model behind the detections: the shipped scorer (scored), none (threshold).
    expected_model = load_scorer().reference if default["name"] == "scored" else None
    assert detection["model"] == expected_model
    listed = client.get(f"/api/v1/sites/{site}/comparisons", headers=auth).json()
    assert [c["detection"] for c in listed] == [detection]

    features = client.get(
        f"/api/v1/sites/{site}/comparisons/{cid}/detections", headers=auth
    ).json()["features"]
    assert features, "the planted slide is found"
    for feature in features:
        props = feature["properties"]
        assert props["method"] == default["name"] and props["model_version"] == expected_model
        low, high = props["uncertainty"]["area_m2_ci95"]
        assert low <= props["area_m2"] <= high
    products = client.get(f"/api/v1/sites/{site}/comparisons/{cid}/products", headers=auth).json()
    assert {"dh", "lod", "detections"} <= {p["kind"] for p in products}


def test_scored_is_refused_while_its_scorer_is_not_installed(
    client: TestClient,
    auth: dict,
    site_and_surveys: tuple[int, int, int],
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    # An installation without the scorer's weights file (a trimmed package).
    monkeypatch.setattr(scored_method, "shipped_scorer_available", lambda: False)
    site, pre, post = site_and_surveys
    response = client.post(
        f"/api/v1/sites/{site}/comparisons",
        json={"pre_survey_id": pre, "post_survey_id": post, "method": "scored"},
        headers=auth,
    )
    assert response.status_code == 422
    assert "scorer of the scored method is not installed" in response.json()["detail"]
    assert client.get(f"/api/v1/sites/{site}/comparisons", headers=auth).json() == []


def test_a_scored_comparison_keeps_its_detections_scorer_and_lod(
    app: FastAPI, client: TestClient, auth: dict, site_and_surveys: tuple[int, int, int],
    tmp_path: Path,
) -> None:  # fmt: skip
    """The score stage's detections become the comparison's detections (rows, product) as
    the vectorize stage's do, and the comparison names the scorer that ran.

    The API runs only the scorer shipped in the package, which this tree may not have yet
    (it is trained separately): the comparison is stored as the API would store it, with a
    scorer of the test's own that takes every candidate (probability ~1).
    """
    site, pre, post = site_and_surveys
    scorer = tmp_path / "scorer-test.json"
    scorer.write_text(
        json.dumps(
            {
                "name": "scorer-test", "version": "1", "traits": ["log_area_px"],
                "mean": [0.0], "scale": [1.0], "coefficients": [0.0], "intercept": 8.0,
                "calibration": [1.0, 0.0], "threshold": 0.5, "card": {},
            }
        )
    )  # fmt: skip
    options = ComparisonOptions.from_dict({"method": "scored", "score": {"scorer": str(scorer)}})
    with app.state.sessionmaker() as session:
        comparison = Comparison(
            site_id=site, pre_survey_id=pre, post_survey_id=post, method="scored",
            parameters=options.to_dict(), status=JobState.queued,
        )  # fmt: skip
        session.add(comparison)
        session.flush()
        job = new_job(
            site, JobKindName.comparison, stages_for("scored"), comparison_id=comparison.id
        )
        session.add(job)
        session.commit()
        cid, job_id = comparison.id, job.id
    run_job_inline(job_id)

    found = client.get(f"/api/v1/sites/{site}/comparisons/{cid}", headers=auth).json()
    assert found["status"] == "succeeded", found
    score = found["summary"]["stages"]["score"]
    assert score["model"] == "scorer-test@1" and score["detections"] >= 1
    detection = found["detection"]
    assert detection["method"] == "scored" and detection["model"] == "scorer-test@1"
    assert detection["lod_m"] == found["summary"]["stages"]["difference"]["lod_m"] > 0
    assert found["summary"]["detections"] == score["detections"]

    features = client.get(
        f"/api/v1/sites/{site}/comparisons/{cid}/detections", headers=auth
    ).json()["features"]
    assert len(features) == score["detections"]
    for feature in features:
        props = feature["properties"]
        assert props["method"] == "scored" and props["model_version"] == "scorer-test@1"
        assert props["score"] > 0.99
        uncertainty = props["uncertainty"]
        assert set(uncertainty) == {
            "area_m2_ci95", "volume_loss_m3_ci95", "volume_gain_m3_ci95", "lod_m",
        }  # fmt: skip
        low, high = uncertainty["volume_loss_m3_ci95"]
        assert low <= props["volume_loss_m3"] <= high
    products = client.get(f"/api/v1/sites/{site}/comparisons/{cid}/products", headers=auth).json()
    assert {p["kind"] for p in products} == {
        "post_coregistered", "dh", "significance", "lod", "detections",
    }  # fmt: skip
