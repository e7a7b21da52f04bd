"""A video survey submitted while its video is still uploading (resumable upload).

The job is queued at once; the upload, when it completes, still joins the survey that is
already processing; an upload refused on completion fails the job with its reason. The
reading of the growing file by a real worker is in tests/integration.
"""

from pathlib import Path

from fastapi import FastAPI
from fastapi.testclient import TestClient
from sqlalchemy import select

from backend.db.models import SurveyFile, Upload
from tests.api.test_survey_sources import new_site, new_source, put_file
from tests.api.test_uploads import create, metadata, patch
from tests.api_helpers import create_video_upload, run_job_inline


def _submit(client: TestClient, auth: dict, site_id: int, survey_id: int):
    return client.post(f"/api/v1/sites/{site_id}/surveys/{survey_id}/process", headers=auth)


def test_a_survey_is_processed_while_its_video_uploads(
    app: FastAPI, client: TestClient, auth: dict, simulated_mounds_survey
) -> None:
    flight, _ = simulated_mounds_survey
    site_id = new_site(client, auth)
    survey = new_source(client, auth, site_id)
    sid = survey["id"]
    refused = _submit(client, auth, site_id, sid)
    assert refused.status_code == 409 and "no video and no log" in refused.json()["detail"]
    assert put_file(client, auth, site_id, sid, flight / "DJI_0001.SRT", "log").status_code == 201
    data = (flight / "DJI_0001.MP4").read_bytes()
    location = create_video_upload(client, auth, site_id, sid, data)
    assert patch(client, auth, location, 0, data[:1000]).status_code == 204

    job = _submit(client, auth, site_id, sid)
    assert job.status_code == 202, job.text
    assert job.json()["stages"][0]["stage"] == "ingest"
    assert (
        client.get(f"/api/v1/sites/{site_id}/surveys/{sid}", headers=auth).json()["status"]
        == "processing"
    )
    # The rest arrives after processing started: the video still joins the survey.
    assert patch(client, auth, location, 1000, data[1000:]).status_code == 204
    assert client.get(location, headers=auth).json()["state"] == "complete"
    with app.state.sessionmaker() as session:
        files = session.scalars(select(SurveyFile).where(SurveyFile.survey_id == sid)).all()
        assert sorted((f.role, f.name) for f in files) == [
            ("log", "DJI_0001.SRT"),
            ("video", "DJI_0001.MP4"),
        ]
        assert session.scalar(select(Upload)).details["streamed"] is True
    assert not list((app.state.settings.storage_dir / "uploads").rglob("*.part"))
    # An upload that was not streamed is still refused once processing started.
    late = metadata(
        site_id=str(site_id), filename="more.srt", purpose="survey_file", survey_id=str(sid),
        role="log",
    )  # fmt: skip
    assert create(client, auth, 10, late).status_code == 409


def test_a_streamed_video_refused_on_completion_fails_the_job(
    app: FastAPI, client: TestClient, auth: dict, simulated_mounds_survey, tmp_path: Path
) -> None:
    flight, _ = simulated_mounds_survey
    site_id = new_site(client, auth)
    sid = new_source(client, auth, site_id)["id"]
    assert put_file(client, auth, site_id, sid, flight / "DJI_0001.SRT", "log").status_code == 201
    data = (flight / "DJI_0001.MP4").read_bytes()
    location = create_video_upload(client, auth, site_id, sid, data, "0" * 64)  # wrong SHA
    job = _submit(client, auth, site_id, sid)
    assert job.status_code == 202, job.text
    assert patch(client, auth, location, 0, data).status_code == 422
    run_job_inline(job.json()["id"], first_stage="ingest")
    done = client.get(f"/api/v1/sites/{site_id}/jobs/{job.json()['id']}", headers=auth).json()
    assert done["state"] == "failed"
    assert done["error"].startswith("ingest: the video upload failed: DJI_0001.MP4 arrived damaged")
    survey = client.get(f"/api/v1/sites/{site_id}/surveys/{sid}", headers=auth).json()
    assert survey["status"] == "failed" and "arrived damaged" in survey["error"]
    with app.state.sessionmaker() as session:
        roles = session.scalars(select(SurveyFile.role).where(SurveyFile.survey_id == sid)).all()
        assert roles == ["log"]
    assert not list((app.state.settings.storage_dir / "uploads").rglob("*.part"))
