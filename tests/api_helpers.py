"""Helpers of the API tests."""

import base64
import hashlib
from pathlib import Path

from fastapi.testclient import TestClient

from backend.config import get_settings
from backend.db.session import get_sessionmaker
from worker.jobs.context import JobContext
from worker.jobs.runner import execute_stage


def job_context() -> JobContext:
    """The job context of this test process's settings, as a worker builds its own."""
    return JobContext.from_settings(get_settings(), get_sessionmaker())


def upload_dsm(
    client: TestClient, auth: dict[str, str], site_id: int, path: Path, captured_at: str
) -> dict:
    response = client.post(
        f"/api/v1/sites/{site_id}/surveys",
        params={"captured_at": captured_at, "filename": path.name},
        content=path.read_bytes(),
        headers={**auth, "Content-Type": "image/tiff"},
    )
    assert response.status_code == 201, response.text
    return response.json()


def request_comparison(client, auth: dict, site: int, pre: int, post: int, method: str, **extra):
    """POST a comparison of surveys `pre` and `post` by `method` (`extra`: more of the body,
    e.g. `parameters`, `run_again`); the response."""
    body = {"pre_survey_id": pre, "post_survey_id": post, "method": method, **extra}
    return client.post(f"/api/v1/sites/{site}/comparisons", json=body, headers=auth)


def run_job_inline(job_id: int, first_stage: str = "align") -> None:
    """Run every stage of a job in this process, exactly as a worker would."""
    stage: str | None = first_stage
    while stage is not None:
        stage = execute_stage(job_context(), job_id, stage)


def create_video_upload(
    client: TestClient,
    auth: dict[str, str],
    site_id: int,
    survey_id: int,
    data: bytes,
    sha256: str | None = None,
) -> str:
    """A resumable upload (tus) of the survey's video DJI_0001.MP4, no byte sent yet; its
    URL. `sha256` defaults to that of `data`."""
    values = {
        "site_id": str(site_id),
        "filename": "DJI_0001.MP4",
        "purpose": "survey_file",
        "survey_id": str(survey_id),
        "role": "video",
        "sha256": sha256 or hashlib.sha256(data).hexdigest(),
    }
    meta = ",".join(f"{k} {base64.b64encode(v.encode()).decode()}" for k, v in values.items())
    created = client.post(
        "/api/v1/uploads",
        headers={
            **auth,
            "Tus-Resumable": "1.0.0",
            "Upload-Length": str(len(data)),
            "Upload-Metadata": meta,
        },
    )
    assert created.status_code == 201, created.text
    return created.headers["Location"]


def join(session, user_id: int, role: str, organisation=None) -> None:
    """Make the user a member with `role` of `organisation` (default: the default one)."""
    from backend.db.models import Membership, Role, default_organisation

    organisation = organisation or default_organisation(session)
    session.add(Membership(organisation=organisation, user_id=user_id, role=Role(role)))
