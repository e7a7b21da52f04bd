"""Sites, surveys and comparisons renamed and deleted; a comparison asked for again is
answered with the one made before (unless run again); each stage of a job keeps its log."""

import pytest
from fastapi import FastAPI
from fastapi.testclient import TestClient

from backend.db.models import Organisation
from backend.services.users import create_user
from tests.api.test_comparisons import create
from tests.api_helpers import join, run_job_inline, upload_dsm
from worker.simulator.dsm_pair import DsmPairPaths

PASSWORD = "landslide-2026"


@pytest.fixture
def site_id(client: TestClient, auth: dict) -> int:
    return client.post("/api/v1/sites", json={"name": "slope"}, headers=auth).json()["id"]


@pytest.fixture
def surveys(client: TestClient, auth: dict, site_id: int, dsm_pair_files: DsmPairPaths):
    pre = upload_dsm(client, auth, site_id, dsm_pair_files.pre, "2026-06-01T10:00:00Z")
    post = upload_dsm(client, auth, site_id, dsm_pair_files.post, "2026-07-01T10:00:00Z")
    return pre["id"], post["id"]


def _signed_in(app: FastAPI, client: TestClient, role: str) -> dict[str, str]:
    with app.state.sessionmaker() as session:
        user = create_user(session, role, PASSWORD)
        session.flush()
        join(session, user.id, role)
        session.commit()
    body = {"username": role, "password": PASSWORD}
    token = client.post("/api/v1/auth/sign-in", json=body).json()["token"]
    return {"Authorization": f"Bearer {token}"}


def test_a_comparison_made_before_is_answered_unless_run_again(
    client: TestClient, auth: dict, site_id: int, surveys: tuple[int, int]
) -> None:
    first = create(client, auth, site_id, *surveys, method="threshold")
    assert first.status_code == 202 and first.json()["existing"] is False
    made = first.json()["comparison"]["id"]
    same = create(client, auth, site_id, *surveys, method="threshold")
    assert same.status_code == 200, same.text
    assert same.json()["existing"] is True
    assert same.json()["comparison"]["id"] == made
    assert same.json()["job"]["id"] == first.json()["job"]["id"]
    # Another method, other parameters or "run again": a new comparison.
    other = create(client, auth, site_id, *surveys, method="scored")
    assert other.status_code == 202 and other.json()["comparison"]["id"] != made
    tuned = create(
        client,
        auth,
        site_id,
        *surveys,
        method="threshold",
        parameters={"difference": {"error_model": "uniform"}},
    )
    assert tuned.status_code == 202 and tuned.json()["comparison"]["id"] != made
    again = create(client, auth, site_id, *surveys, method="threshold", run_again=True)
    assert again.status_code == 202 and again.json()["comparison"]["id"] != made
    listed = client.get(f"/api/v1/sites/{site_id}/comparisons", headers=auth).json()
    assert len(listed) == 4


def test_surveys_and_comparisons_are_renamed_by_analysts_not_viewers(
    app: FastAPI, client: TestClient, auth: dict, site_id: int, surveys: tuple[int, int]
) -> None:
    analyst, viewer = _signed_in(app, client, "analyst"), _signed_in(app, client, "viewer")
    base = f"/api/v1/sites/{site_id}"
    comparison = create(client, auth, site_id, *surveys, name="June to July").json()
    assert comparison["comparison"]["name"] == "June to July"
    cid = comparison["comparison"]["id"]
    renamed = client.patch(f"{base}/surveys/{surveys[0]}", json={"name": " June "}, headers=analyst)
    assert renamed.status_code == 200 and renamed.json()["name"] == "June"
    named = client.patch(f"{base}/comparisons/{cid}", json={"name": "Storm"}, headers=analyst)
    assert named.status_code == 200 and named.json()["name"] == "Storm"
    for path in (f"surveys/{surveys[0]}", f"comparisons/{cid}"):
        refused = client.patch(f"{base}/{path}", json={"name": "x"}, headers=viewer)
        assert refused.status_code == 403
        assert "this needs the role analyst" in refused.json()["detail"]
    missing = client.patch(f"{base}/surveys/999", json={"name": "x"}, headers=analyst)
    assert missing.status_code == 404
    empty = client.patch(f"{base}/surveys/{surveys[0]}", json={"name": ""}, headers=analyst)
    assert empty.status_code == 422
    assert client.patch(base, json={"name": "North slope"}, headers=analyst).status_code == 403
    audit = client.get(f"/api/v1/organisations/{_organisation(app)}/audit", headers=auth)
    actions = [e["action"] for e in audit.json()]
    assert {"survey.update", "comparison.update"} <= set(actions)


def _organisation(app: FastAPI) -> int:
    with app.state.sessionmaker() as session:
        return session.query(Organisation).filter_by(is_default=True).one().id


def test_deleting_goes_from_comparisons_to_surveys_to_the_site(
    app: FastAPI, client: TestClient, auth: dict, site_id: int, surveys: tuple[int, int]
) -> None:
    manager, analyst = _signed_in(app, client, "manager"), _signed_in(app, client, "analyst")
    base = f"/api/v1/sites/{site_id}"
    cid = create(client, auth, site_id, *surveys).json()["comparison"]["id"]
    assert client.delete(f"{base}/comparisons/{cid}", headers=analyst).status_code == 403
    used = client.delete(f"{base}/surveys/{surveys[0]}", headers=manager)
    assert used.status_code == 409 and f"comparisons {cid}" in used.json()["detail"]
    assert client.delete(f"{base}/comparisons/{cid}", headers=manager).status_code == 204
    assert client.delete(f"{base}/surveys/{surveys[0]}", headers=manager).status_code == 204
    assert [s["id"] for s in client.get(f"{base}/surveys", headers=auth).json()] == [surveys[1]]
    assert client.delete(base, headers=manager).status_code == 204
    assert client.get(base, headers=auth).status_code == 404


def test_each_stage_keeps_its_log(
    client: TestClient, auth: dict, site_id: int, surveys: tuple[int, int]
) -> None:
    job_id = create(client, auth, site_id, *surveys, method="threshold").json()["job"]["id"]
    run_job_inline(job_id)
    job = client.get(f"/api/v1/sites/{site_id}/jobs/{job_id}", headers=auth).json()
    for stage in job["stages"]:
        assert stage["log"][0].endswith("INFO attempt 1 started"), stage
        assert " INFO succeeded in " in stage["log"][-1], stage
