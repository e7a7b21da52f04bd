"""Helpers of the API tests."""

from pathlib import Path

from fastapi.testclient import TestClient

from worker.jobs.runner import execute_stage


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


def run_job_inline(job_id: int, first_stage: str = "align") -> None:
    """Run every stage of a job in this process, exactly as a worker would."""
    stage: str | None = first_stage
    while stage is not None:
        stage = execute_stage(job_id, stage)
