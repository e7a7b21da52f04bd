"""A survey uploaded as video + flight log becomes a DSM product that can be compared.

The video is the simulator's (tests/conftest.py: 6 s over the mound field, stand-alone
GPS). Bad files are refused with a message naming what is wrong and leave nothing behind.
"""

import json
from pathlib import Path

import numpy as np
import pytest
from fastapi.testclient import TestClient
from sqlalchemy import func, select

from backend.db.models import StoredFile, SurveyFile
from tests.api_helpers import run_job_inline, upload_dsm
from tests.simulator.simtest_support import image_run


def new_site(client: TestClient, auth: dict[str, str], name: str = "Mounds") -> int:
    response = client.post("/api/v1/sites", json={"name": name}, headers=auth)
    assert response.status_code == 201, response.text
    return response.json()["id"]


def new_source(client: TestClient, auth: dict[str, str], site_id: int, kind: str = "video") -> dict:
    response = client.post(
        f"/api/v1/sites/{site_id}/surveys/sources",
        json={"kind": kind, "name": "July flight", "captured_at": "2026-07-01T09:00:00Z"},
        headers=auth,
    )
    assert response.status_code == 201, response.text
    assert response.json()["status"] == "receiving"
    return response.json()


def put_file(client, auth, site_id, survey_id, path: Path, role: str, name: str | None = None):
    return client.put(
        f"/api/v1/sites/{site_id}/surveys/{survey_id}/files/{name or path.name}",
        params={"role": role},
        content=path.read_bytes(),
        headers={**auth, "Content-Type": "application/octet-stream"},
    )


def stored_counts(app) -> tuple[int, int, int]:
    """(stored file rows, survey file rows, files on disk under surveys/)."""
    with app.state.sessionmaker() as session:
        rows = session.scalar(select(func.count()).select_from(StoredFile))
        links = session.scalar(select(func.count()).select_from(SurveyFile))
    root = app.state.settings.storage_dir / "surveys"
    on_disk = sum(1 for p in root.rglob("*") if p.is_file()) if root.exists() else 0
    return rows, links, on_disk


def test_video_and_log_become_a_dsm_that_can_be_compared(
    app, client, auth, simulated_mounds_survey
):
    flight, truth = simulated_mounds_survey
    site_id = new_site(client, auth)
    survey = new_source(client, auth, site_id)
    sid = survey["id"]
    video = put_file(client, auth, site_id, sid, flight / "DJI_0001.MP4", "video")
    assert video.status_code == 201, video.text
    assert video.json()["file"]["size_bytes"] == (flight / "DJI_0001.MP4").stat().st_size
    log = put_file(client, auth, site_id, sid, flight / "DJI_0001.SRT", "log")
    assert log.status_code == 201, log.text
    listed = client.get(f"/api/v1/sites/{site_id}/surveys/{sid}/files", headers=auth).json()
    assert sorted(f["role"] for f in listed) == ["log", "video"]

    job = client.post(f"/api/v1/sites/{site_id}/surveys/{sid}/process", headers=auth)
    assert job.status_code == 202, job.text
    assert [s["stage"] for s in job.json()["stages"]] == [
        "ingest",
        "frames",
        "reconstruct",
        "georeference",
        "dsm",
    ]
    again = client.post(f"/api/v1/sites/{site_id}/surveys/{sid}/process", headers=auth)
    assert again.status_code == 409 and "processing" in again.json()["detail"]

    run_job_inline(job.json()["id"], first_stage="ingest")
    done = client.get(f"/api/v1/sites/{site_id}/jobs/{job.json()['id']}", headers=auth).json()
    assert done["state"] == "succeeded", done
    survey = client.get(f"/api/v1/sites/{site_id}/surveys/{sid}", headers=auth).json()
    assert survey["status"] == "ready"
    assert survey["crs"].startswith("EPSG:326")  # the survey's UTM zone
    assert survey["resolution_m"] == pytest.approx(0.02, rel=0.3)
    products = {
        p["kind"]: p
        for p in client.get(f"/api/v1/sites/{site_id}/surveys/{sid}/products", headers=auth).json()
    }
    assert set(products) == {"dsm", "points", "trajectory", "report"}
    path = client.get(products["trajectory"]["download_url"], headers=auth)
    assert path.status_code == 200
    line = json.loads(path.content)
    coords = np.array(line["geometry"]["coordinates"])
    assert line["geometry"]["type"] == "LineString" and len(coords) >= 10
    # The flight was at 7 m over a 20 m field: the path spans metres, not kilometres.
    span_deg = coords[:, :2].max(axis=0) - coords[:, :2].min(axis=0)
    assert 5e-6 < span_deg.max() < 5e-4

    # The reconstructed DSM feeds a comparison with a DSM uploaded as a file.
    pre = upload_dsm(client, auth, site_id, truth / "dsm.tif", "2026-06-01T09:00:00Z")
    created = client.post(
        f"/api/v1/sites/{site_id}/comparisons",
        json={"pre_survey_id": pre["id"], "post_survey_id": sid, "method": "threshold"},
        headers=auth,
    )
    assert created.status_code == 202, created.text
    run_job_inline(created.json()["job"]["id"])
    comparison = client.get(
        f"/api/v1/sites/{site_id}/comparisons/{created.json()['comparison']['id']}", headers=auth
    ).json()
    assert comparison["status"] == "succeeded", comparison


def test_bad_files_are_refused_and_leave_nothing(
    app, client, auth, simulated_mounds_survey, tmp_path
):
    flight, _ = simulated_mounds_survey
    site_id = new_site(client, auth)
    sid = new_source(client, auth, site_id)["id"]
    before = stored_counts(app)

    corrupt = tmp_path / "broken.mp4"
    corrupt.write_bytes((flight / "DJI_0001.MP4").read_bytes()[:2000])
    response = put_file(client, auth, site_id, sid, corrupt, "video")
    assert response.status_code == 422 and "broken.mp4" in response.json()["detail"]

    not_a_log = tmp_path / "notes.csv"
    not_a_log.write_text("hello,world\n1,2\n")
    response = put_file(client, auth, site_id, sid, not_a_log, "log")
    assert response.status_code == 422 and "notes.csv" in response.json()["detail"]

    response = put_file(client, auth, site_id, sid, not_a_log, "log", name="flight.exe")
    assert response.status_code == 422 and ".srt" in response.json()["detail"]
    response = put_file(client, auth, site_id, sid, not_a_log, "sound", name="a.csv")
    assert response.status_code == 422 and "role" in response.json()["detail"]
    response = put_file(client, auth, site_id, sid, not_a_log, "image", name="photo.jpg")
    assert response.status_code == 409 and "video and log" in response.json()["detail"]
    assert stored_counts(app) == before

    process = client.post(f"/api/v1/sites/{site_id}/surveys/{sid}/process", headers=auth)
    assert process.status_code == 409
    assert process.json()["detail"] == f"survey {sid} has no video and no log yet"


def test_image_survey_rules(app, client, auth, tmp_path):
    site_id = new_site(client, auth)
    sid = new_source(client, auth, site_id, kind="images")["id"]
    import cv2

    plain = tmp_path / "IMG_0001.JPG"
    cv2.imwrite(str(plain), np.full((64, 64, 3), 128, np.uint8))
    response = put_file(client, auth, site_id, sid, plain, "image")
    assert response.status_code == 422
    assert "IMG_0001.JPG: no GPS position" in response.json()["detail"]
    process = client.post(f"/api/v1/sites/{site_id}/surveys/{sid}/process", headers=auth)
    assert process.status_code == 409 and "at least 3 geotagged photos" in process.json()["detail"]
    dsm_kind = client.post(
        f"/api/v1/sites/{site_id}/surveys/sources",
        json={"kind": "dsm", "name": "x", "captured_at": "2026-07-01T09:00:00Z"},
        headers=auth,
    )
    assert dsm_kind.status_code == 422 and "upload the DSM" in dsm_kind.json()["detail"]
    bad_option = client.post(
        f"/api/v1/sites/{site_id}/surveys/sources",
        json={
            "kind": "video",
            "name": "x",
            "captured_at": "2026-07-01T09:00:00Z",
            "options": {"methd": "sfm"},
        },
        headers=auth,
    )
    assert bad_option.status_code == 422 and "methd" in bad_option.json()["detail"]


def test_deleting_a_source_survey_removes_its_files(app, client, auth, simulated_mounds_survey):
    flight, _ = simulated_mounds_survey
    site_id = new_site(client, auth)
    sid = new_source(client, auth, site_id)["id"]
    before = stored_counts(app)
    uploaded = put_file(client, auth, site_id, sid, flight / "DJI_0001.SRT", "log").json()
    assert stored_counts(app) == (before[0] + 1, before[1] + 1, before[2] + 1)
    removed = client.delete(
        f"/api/v1/sites/{site_id}/surveys/{sid}/files/{uploaded['id']}", headers=auth
    )
    assert removed.status_code == 204
    assert stored_counts(app) == before
    put_file(client, auth, site_id, sid, flight / "DJI_0001.SRT", "log")
    assert client.delete(f"/api/v1/sites/{site_id}/surveys/{sid}", headers=auth).status_code == 204
    assert stored_counts(app) == (before[0], before[1], 0)


def test_image_set_becomes_a_dsm(app, client, auth):
    run = image_run()  # the simulator's photos of the mound field, EXIF GPS and DJI XMP
    survey_meta = run.steps[0]["surveys"][0]
    photos = sorted((run.root / survey_meta["images_dir"]).glob("DJI_*.JPG"))
    site_id = new_site(client, auth)
    sid = new_source(client, auth, site_id, kind="images")["id"]
    for photo in photos:
        response = put_file(client, auth, site_id, sid, photo, "image")
        assert response.status_code == 201, response.text
    job = client.post(f"/api/v1/sites/{site_id}/surveys/{sid}/process", headers=auth)
    assert job.status_code == 202, job.text
    run_job_inline(job.json()["id"], first_stage="ingest")
    done = client.get(f"/api/v1/sites/{site_id}/jobs/{job.json()['id']}", headers=auth).json()
    assert done["state"] == "succeeded", done
    reconstruct = next(s for s in done["stages"] if s["stage"] == "reconstruct")["result"]
    assert reconstruct["method"] == "sfm"
    assert reconstruct["sfm"]["registered"] >= 0.8 * len(photos)
    survey = client.get(f"/api/v1/sites/{site_id}/surveys/{sid}", headers=auth).json()
    assert survey["status"] == "ready" and survey["crs"].startswith("EPSG:326")


def test_a_log_with_unreadable_blocks_is_kept_and_its_upload_says_which(app, client, auth):
    """A Mavic Pro log with `GPS(N/A,N/A,3)` blocks: accepted, and the answer to the upload
    (and the survey's file list) names the blocks the reader set aside."""
    site = new_site(client, auth)
    survey = new_source(client, auth, site)
    log = Path(__file__).parents[1] / "reconstruction/fixtures/flight_logs/mavic_pro_gps_na.srt"
    response = put_file(client, auth, site, survey["id"], log, "log")
    assert response.status_code == 201, response.text
    warnings = response.json()["warnings"]
    assert warnings and any("line" in w for w in warnings), warnings
    listed = client.get(f"/api/v1/sites/{site}/surveys/{survey['id']}/files", headers=auth)
    assert listed.json()[0]["warnings"] == warnings
