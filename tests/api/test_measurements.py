"""Measuring on the map over the API: a profile across a landslide and the volume inside
its polygon, which agree with what the comparison says of it."""

import pytest
from fastapi.testclient import TestClient
from shapely.geometry import shape

from tests.api_helpers import run_job_inline, upload_dsm
from worker.simulator.dsm_pair import DsmPairPaths


@pytest.fixture
def compared(client: TestClient, auth: dict, dsm_pair_files: DsmPairPaths) -> tuple[str, dict]:
    site = client.post("/api/v1/sites", json={"name": "measured slope"}, headers=auth).json()
    base = f"/api/v1/sites/{site['id']}"
    pre = upload_dsm(client, auth, site["id"], dsm_pair_files.pre, "2026-06-01T10:00:00Z")
    post = upload_dsm(client, auth, site["id"], dsm_pair_files.post, "2026-07-01T10:00:00Z")
    created = client.post(
        f"{base}/comparisons",
        json={"pre_survey_id": pre["id"], "post_survey_id": post["id"], "method": "threshold"},
        headers=auth,
    ).json()
    run_job_inline(created["job"]["id"])
    comparison = created["comparison"]["id"]
    detections = client.get(f"{base}/comparisons/{comparison}/detections", headers=auth).json()
    biggest = max(detections["features"], key=lambda f: f["properties"]["area_m2"])
    return f"{base}/comparisons/{comparison}", biggest


def test_the_volume_inside_a_detection_is_the_detections_volume(
    client: TestClient, auth: dict, compared: tuple[str, dict]
) -> None:
    url, detection = compared
    answer = client.post(f"{url}/volume", json={"polygon": detection["geometry"]}, headers=auth)
    assert answer.status_code == 200, answer.text
    volume = answer.json()
    # The tool over the detection's own polygon gives the comparison's own volumes.
    props = detection["properties"]
    assert volume["cut_m3"] == pytest.approx(props["volume_loss_m3"], rel=0.02)
    assert volume["fill_m3"] == pytest.approx(props["volume_gain_m3"], rel=0.02)
    assert volume["area_m2"] == pytest.approx(props["area_m2"], rel=0.02)
    assert volume["cut_m3"] >= volume["cut_beyond_lod_m3"] > 100
    assert volume["net_m3"] == pytest.approx(volume["fill_m3"] - volume["cut_m3"], abs=0.02)
    assert volume["lod_m"] > 0 and volume["area_m2"] > 0


def test_a_profile_across_a_detection_shows_the_ground_moved(
    client: TestClient, auth: dict, compared: tuple[str, dict]
) -> None:
    url, detection = compared
    area = shape(detection["geometry"])
    west, _, east, _ = area.bounds
    y = area.representative_point().y
    line = {"type": "LineString", "coordinates": [[west - 0.0003, y], [east + 0.0003, y]]}
    answer = client.post(f"{url}/profile", json={"line": line, "samples": 100}, headers=auth)
    assert answer.status_code == 200, answer.text
    profile = answer.json()
    assert len(profile["distance_m"]) == 100 and profile["length_m"] > 20
    pairs = [
        (pre, post)
        for pre, post in zip(profile["heights_m"]["pre"], profile["heights_m"]["post"], strict=True)
        if pre is not None and post is not None
    ]
    change = [abs(post - pre) for pre, post in pairs]
    assert max(change) > 1.0  # the slid mass (lowered on its scar, raised on its deposit)
    assert change[0] < 0.3 and change[-1] < 0.3  # stable ground on both sides


def test_bad_geometries_are_refused_naming_what_is_wrong(
    client: TestClient, auth: dict, compared: tuple[str, dict]
) -> None:
    url, _ = compared
    point = {"type": "Point", "coordinates": [0, 0]}
    assert client.post(f"{url}/volume", json={"polygon": point}, headers=auth).status_code == 422
    far = {"type": "Polygon", "coordinates": [[[0, 0], [0.001, 0], [0.001, 0.001], [0, 0]]]}
    refused = client.post(f"{url}/volume", json={"polygon": far}, headers=auth)
    assert refused.status_code == 422 and "outside" in refused.json()["detail"]
    line = {"type": "LineString", "coordinates": [[1, 1]]}
    assert client.post(f"{url}/profile", json={"line": line}, headers=auth).status_code == 422


def test_heights_under_the_cursor_on_a_detection(
    client: TestClient, auth: dict, compared: tuple[str, dict]
) -> None:
    url, detection = compared
    point = shape(detection["geometry"]).representative_point()
    answer = client.get(f"{url}/heights", params={"lon": point.x, "lat": point.y}, headers=auth)
    assert answer.status_code == 200, answer.text
    heights = answer.json()
    assert set(heights) == {"pre", "post", "dh"}
    assert heights["dh"] == pytest.approx(heights["post"] - heights["pre"], abs=0.05)
    assert abs(heights["dh"]) > 0.1  # inside the landslide
    off_site = client.get(f"{url}/heights", params={"lon": 0.0, "lat": 0.0}, headers=auth)
    assert off_site.json() == {"pre": None, "post": None, "dh": None}
    assert (
        client.get(f"{url}/heights", params={"lon": 200, "lat": 0}, headers=auth).status_code == 422
    )
