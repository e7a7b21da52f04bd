"""A detection's history over the API: the same ground in the site's other comparisons."""

from fastapi.testclient import TestClient

from tests.api_helpers import run_job_inline, upload_dsm
from worker.simulator.dsm_pair import DsmPairPaths


def compare(client: TestClient, auth: dict, site: int, pre: int, post: int) -> int:
    created = client.post(
        f"/api/v1/sites/{site}/comparisons",
        json={"pre_survey_id": pre, "post_survey_id": post, "method": "threshold"},
        headers=auth,
    ).json()
    run_job_inline(created["job"]["id"])
    return created["comparison"]["id"]


def test_a_landslide_is_followed_across_comparisons(
    client: TestClient, auth: dict, dsm_pair_files: DsmPairPaths
) -> None:
    site = client.post("/api/v1/sites", json={"name": "followed"}, headers=auth).json()["id"]
    june = upload_dsm(client, auth, site, dsm_pair_files.pre, "2026-06-01T10:00:00Z")["id"]
    july = upload_dsm(client, auth, site, dsm_pair_files.post, "2026-07-01T10:00:00Z")["id"]
    # The slope flown again in August, unchanged since July: the scar is still there.
    august = upload_dsm(client, auth, site, dsm_pair_files.post, "2026-08-01T10:00:00Z")["id"]
    later = compare(client, auth, site, june, august)
    first = compare(client, auth, site, june, july)
    unchanged = compare(client, auth, site, july, august)
    base = f"/api/v1/sites/{site}/comparisons"
    detections = client.get(f"{base}/{first}/detections", headers=auth).json()["features"]
    slide = max(detections, key=lambda f: f["properties"]["area_m2"])
    answer = client.get(f"{base}/{first}/detections/{slide['id']}/history", headers=auth)
    assert answer.status_code == 200, answer.text
    history = answer.json()
    # In time order of the post surveys: July (this one), then August; the comparison of
    # July with August found nothing there.
    assert [h["comparison_id"] for h in history] == [first, later]
    assert history[0]["this"] and history[0]["overlap"] == 1.0
    assert history[0]["label"] == slide["properties"]["label"]
    assert not history[1]["this"] and history[1]["overlap"] > 0.8
    assert (
        abs(history[1]["area_m2"] - slide["properties"]["area_m2"])
        < 0.2 * slide["properties"]["area_m2"]
    )
    assert unchanged not in {h["comparison_id"] for h in history}
    missing = client.get(f"{base}/{later}/detections/{slide['id']}/history", headers=auth)
    assert missing.status_code == 404
