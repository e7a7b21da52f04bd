"""A survey's files are taken in any order and at any time before processing consumes
them: a video upload that completes after processing was asked for, a video upload made
again after one was cancelled, a failed survey fixed by replacing a file and processed
again (its failed job retried), a failed survey deleted with its unfinished uploads, and
the site's unfinished uploads listed for the page to resume or cancel."""

from fastapi import FastAPI
from fastapi.testclient import TestClient
from sqlalchemy import select, update

from backend.db.models import Job, StageRun, Upload
from tests.api.test_survey_sources import new_site, new_source, put_file
from tests.api.test_uploads import TUS, patch
from tests.api_helpers import create_video_upload, run_job_inline


def _process(client: TestClient, auth: dict, site_id: int, survey_id: int):
    return client.post(f"/api/v1/sites/{site_id}/surveys/{survey_id}/process", headers=auth)


def _survey(client: TestClient, auth: dict, site_id: int, survey_id: int) -> dict:
    return client.get(f"/api/v1/sites/{site_id}/surveys/{survey_id}", headers=auth).json()


def _files(client: TestClient, auth: dict, site_id: int, survey_id: int) -> dict[str, int]:
    listed = client.get(f"/api/v1/sites/{site_id}/surveys/{survey_id}/files", headers=auth)
    return {f["role"]: f["id"] for f in listed.json()}


def _failed_survey(client: TestClient, auth: dict, flight) -> tuple[int, int, int, bytes]:
    """A video survey whose job failed: its video arrived damaged. (site, survey, job,
    the video's bytes)."""
    site_id = new_site(client, auth)
    sid = new_source(client, auth, site_id)["id"]
    assert put_file(client, auth, site_id, sid, flight / "DJI_0001.SRT", "log").status_code == 201
    data = (flight / "DJI_0001.MP4").read_bytes()
    location = create_video_upload(client, auth, site_id, sid, data, "0" * 64)  # wrong SHA
    job = _process(client, auth, site_id, sid)
    assert job.status_code == 202, job.text
    assert patch(client, auth, location, 0, data).status_code == 422
    run_job_inline(job.json()["id"], first_stage="ingest")
    assert _survey(client, auth, site_id, sid)["status"] == "failed"
    return site_id, sid, job.json()["id"], data


def test_a_video_completing_after_processing_was_asked_is_taken(
    app: FastAPI, client: TestClient, auth: dict, simulated_mounds_survey
) -> None:
    """The race of the page: the upload's request began before processing was asked for
    and completes after. Whether the survey takes the video depends on the survey alone."""
    flight, _ = simulated_mounds_survey
    site_id = new_site(client, auth)
    sid = new_source(client, auth, site_id)["id"]
    assert put_file(client, auth, site_id, sid, flight / "DJI_0001.SRT", "log").status_code == 201
    data = (flight / "DJI_0001.MP4").read_bytes()
    location = create_video_upload(client, auth, site_id, sid, data)
    assert _process(client, auth, site_id, sid).status_code == 202
    with app.state.sessionmaker() as session:  # as the upload was read before: not marked
        upload = session.scalar(select(Upload))
        upload.details = {k: v for k, v in upload.details.items() if k != "streamed"}
        session.commit()
    assert patch(client, auth, location, 0, data).status_code == 204
    assert client.get(location, headers=auth).json()["state"] == "complete"
    assert set(_files(client, auth, site_id, sid)) == {"log", "video"}


def test_a_video_upload_made_again_while_processing_is_taken(
    client: TestClient, auth: dict, simulated_mounds_survey
) -> None:
    """Processing waits for the video: one cancelled and made again is still taken; what
    processing has consumed (the log) is not."""
    flight, _ = simulated_mounds_survey
    site_id = new_site(client, auth)
    sid = new_source(client, auth, site_id)["id"]
    assert put_file(client, auth, site_id, sid, flight / "DJI_0001.SRT", "log").status_code == 201
    data = (flight / "DJI_0001.MP4").read_bytes()
    first = create_video_upload(client, auth, site_id, sid, data)
    assert _process(client, auth, site_id, sid).status_code == 202
    assert client.delete(first, headers={**auth, **TUS}).status_code == 204
    again = create_video_upload(client, auth, site_id, sid, data)
    assert patch(client, auth, again, 0, data).status_code == 204
    assert set(_files(client, auth, site_id, sid)) == {"log", "video"}
    refused = put_file(client, auth, site_id, sid, flight / "DJI_0001.SRT", "log", "more.srt")
    assert refused.status_code == 409
    assert "read when processing started" in refused.json()["detail"]


def test_a_failed_survey_is_retried_once_its_cause_is_gone(
    app: FastAPI, client: TestClient, auth: dict, simulated_mounds_survey
) -> None:
    flight, _ = simulated_mounds_survey
    site_id, sid, job_id, data = _failed_survey(client, auth, flight)
    job = client.get(f"/api/v1/sites/{site_id}/jobs/{job_id}", headers=auth).json()
    ingest = job["stages"][0]
    assert ingest["log"][0].endswith("INFO attempt 1 started")
    assert "ERROR failed: the video upload failed" in ingest["log"][-1]
    # The cause: the damaged video. Sent again, whole, to the failed survey: taken.
    location = create_video_upload(client, auth, site_id, sid, data)
    assert patch(client, auth, location, 0, data).status_code == 204
    assert set(_files(client, auth, site_id, sid)) == {"log", "video"}
    retried = client.post(f"/api/v1/sites/{site_id}/jobs/{job_id}/retry", headers=auth)
    assert retried.status_code == 202, retried.text
    assert retried.json()["state"] == "queued"
    assert _survey(client, auth, site_id, sid)["status"] == "processing"


def test_a_failed_survey_is_fixed_by_replacing_a_file_and_processed_again(
    app: FastAPI, client: TestClient, auth: dict, simulated_mounds_survey
) -> None:
    flight, _ = simulated_mounds_survey
    site_id, sid, job_id, data = _failed_survey(client, auth, flight)
    location = create_video_upload(client, auth, site_id, sid, data)
    assert patch(client, auth, location, 0, data).status_code == 204
    with app.state.sessionmaker() as session:  # as if ingest had finished on the old files
        session.execute(
            update(StageRun)
            .where(StageRun.job_id == job_id, StageRun.stage == "ingest")
            .values(state="succeeded", progress=1.0)
        )
        session.commit()
    files = _files(client, auth, site_id, sid)
    twice = put_file(client, auth, site_id, sid, flight / "DJI_0001.SRT", "log", "B.SRT")
    assert twice.status_code == 409 and "delete that file first" in twice.json()["detail"]
    removed = client.delete(
        f"/api/v1/sites/{site_id}/surveys/{sid}/files/{files['log']}", headers=auth
    )
    assert removed.status_code == 204
    with app.state.sessionmaker() as session:  # its finished stages read the old log
        states = session.scalars(select(StageRun.state).where(StageRun.job_id == job_id)).all()
        assert set(states) == {"pending"}
    replaced = put_file(client, auth, site_id, sid, flight / "DJI_0001.SRT", "log")
    assert replaced.status_code == 201, replaced.text
    again = _process(client, auth, site_id, sid)
    assert again.status_code == 202, again.text
    assert again.json()["id"] == job_id  # the failed job, run again from its first stage
    assert {s["state"] for s in again.json()["stages"]} == {"pending"}
    assert _survey(client, auth, site_id, sid)["status"] == "processing"
    with app.state.sessionmaker() as session:
        assert len(session.scalars(select(Job).where(Job.survey_id == sid)).all()) == 1


def test_a_failed_survey_is_deleted_with_its_unfinished_uploads(
    app: FastAPI, client: TestClient, auth: dict, simulated_mounds_survey
) -> None:
    flight, _ = simulated_mounds_survey
    site_id, sid, _job_id, data = _failed_survey(client, auth, flight)
    create_video_upload(client, auth, site_id, sid, data)  # started, never finished
    listed = client.get(f"/api/v1/sites/{site_id}/uploads", headers=auth).json()
    assert [(u["filename"], u["role"], u["survey_id"]) for u in listed] == [
        ("DJI_0001.MP4", "video", sid)
    ]
    assert client.delete(f"/api/v1/sites/{site_id}/surveys/{sid}", headers=auth).status_code == 204
    assert client.get(f"/api/v1/sites/{site_id}/surveys/{sid}", headers=auth).status_code == 404
    assert client.get(f"/api/v1/sites/{site_id}/uploads", headers=auth).json() == []
    assert not list((app.state.settings.storage_dir / "uploads").rglob("*.part"))


def test_unfinished_uploads_are_listed_with_their_offset_until_cancelled(
    client: TestClient, auth: dict, simulated_mounds_survey
) -> None:
    flight, _ = simulated_mounds_survey
    site_id = new_site(client, auth)
    sid = new_source(client, auth, site_id)["id"]
    data = (flight / "DJI_0001.MP4").read_bytes()
    location = create_video_upload(client, auth, site_id, sid, data)
    assert patch(client, auth, location, 0, data[:1000]).status_code == 204
    (upload,) = client.get(f"/api/v1/sites/{site_id}/uploads", headers=auth).json()
    assert upload["offset"] == 1000 and upload["length"] == len(data)
    assert upload["state"] == "receiving" and upload["id"] in location
    assert client.delete(location, headers={**auth, **TUS}).status_code == 204
    assert client.get(f"/api/v1/sites/{site_id}/uploads", headers=auth).json() == []
