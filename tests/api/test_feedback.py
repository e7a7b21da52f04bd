"""People mark detections as confirmed or false alarm; the verdicts, with who and when,
export as training labels."""

import pytest
from fastapi import FastAPI
from fastapi.testclient import TestClient

from backend.services.users import create_user
from tests.api_helpers import join
from tests.monitoring_helpers import finished_comparison
from worker.simulator.dsm_pair import DsmPairPaths


@pytest.fixture
def ids(client: TestClient, auth: dict, dsm_pair_files: DsmPairPaths) -> dict[str, int]:
    return finished_comparison(client, auth, dsm_pair_files)


@pytest.fixture
def maria(app: FastAPI, client: TestClient) -> dict[str, str]:
    with app.state.sessionmaker() as session:
        user = create_user(session, "maria", "landslide-2026")
        join(session, user.id, "analyst")  # confirms detections
        session.commit()
    body = {"username": "maria", "password": "landslide-2026"}
    token = client.post("/api/v1/auth/sign-in", json=body).json()["token"]
    return {"Authorization": f"Bearer {token}"}


def detections_of(client: TestClient, auth: dict, ids: dict) -> list[dict]:
    url = f"/api/v1/sites/{ids['site']}/comparisons/{ids['comparison']}/detections"
    return client.get(url, headers=auth).json()["features"]


def feedback_url(ids: dict, detection_id: int) -> str:
    return (
        f"/api/v1/sites/{ids['site']}/comparisons/{ids['comparison']}"
        f"/detections/{detection_id}/feedback"
    )


def test_verdicts_are_kept_with_who_and_when(
    client: TestClient, auth: dict, maria: dict, ids: dict
) -> None:
    detection = detections_of(client, auth, ids)[0]
    assert detection["properties"]["feedback"] == {
        "confirmed": 0,
        "false_alarm": 0,
        "latest": None,
    }
    url = feedback_url(ids, detection["id"])
    first = client.put(url, json={"verdict": "false_alarm"}, headers=maria)
    assert first.status_code == 200, first.text
    changed = client.put(url, json={"verdict": "confirmed", "note": "fresh scarp"}, headers=maria)
    assert changed.json()["id"] == first.json()["id"]  # one verdict per person, changed
    client.put(url, json={"verdict": "false_alarm"}, headers=auth)
    verdicts = {f["author"]: f for f in client.get(url, headers=auth).json()}
    assert set(verdicts) == {"maria", "token tests"}
    assert (
        verdicts["maria"]["verdict"] == "confirmed" and verdicts["maria"]["note"] == "fresh scarp"
    )
    assert verdicts["maria"]["updated_at"] >= verdicts["maria"]["created_at"]
    summary = detections_of(client, auth, ids)[0]["properties"]["feedback"]
    assert summary["confirmed"] == 1 and summary["false_alarm"] == 1
    assert summary["latest"]["author"] == "token tests"
    assert client.delete(url, headers=maria).status_code == 204
    assert client.delete(url, headers=maria).status_code == 404
    assert [f["author"] for f in client.get(url, headers=auth).json()] == ["token tests"]


def test_training_labels_export_as_geojson(
    client: TestClient, auth: dict, maria: dict, ids: dict
) -> None:
    detection = detections_of(client, auth, ids)[0]
    client.put(feedback_url(ids, detection["id"]), json={"verdict": "confirmed"}, headers=maria)
    response = client.get(f"/api/v1/sites/{ids['site']}/training-labels", headers=auth)
    assert response.status_code == 200
    assert response.headers["content-type"] == "application/geo+json"
    assert "attachment" in response.headers["content-disposition"]
    [feature] = response.json()["features"]
    props = feature["properties"]
    assert feature["geometry"] == detection["geometry"]
    assert props["label"] == 1 and props["verdict"] == "confirmed" and props["author"] == "maria"
    assert props["pre_survey_id"] == ids["pre"] and props["post_survey_id"] == ids["post"]
    assert props["pre_dsm_product_id"] and props["post_dsm_product_id"]
    assert props["method"] == "threshold" and props["at"]


def test_verdicts_are_checked(client: TestClient, auth: dict, ids: dict) -> None:
    detection = detections_of(client, auth, ids)[0]
    bad = client.put(feedback_url(ids, detection["id"]), json={"verdict": "maybe"}, headers=auth)
    assert bad.status_code == 422
    assert (
        client.put(
            feedback_url(ids, 999999), json={"verdict": "confirmed"}, headers=auth
        ).status_code
        == 404
    )
    other = client.post("/api/v1/sites", json={"name": "other"}, headers=auth).json()["id"]
    foreign = feedback_url({**ids, "site": other}, detection["id"])
    assert client.put(foreign, json={"verdict": "confirmed"}, headers=auth).status_code == 404


def test_detection_properties_say_method_and_model(
    client: TestClient, auth: dict, ids: dict
) -> None:
    props = detections_of(client, auth, ids)[0]["properties"]
    assert props["method"] == "threshold" and props["model_version"] is None
    cells = client.get(
        f"/api/v1/sites/{ids['site']}/comparisons/{ids['comparison']}/cells", headers=auth
    )
    assert cells.status_code == 200 and cells.json()["features"] == []
