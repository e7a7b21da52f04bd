"""A report is built by a real Celery worker as a job: a transient failure of its stage is
retried with backoff and recorded on the stage, as for any job (embedded default)."""

import re
from collections.abc import Callable
from pathlib import Path

import pytest

from backend.config import Settings
from tests.integration.conftest import SlidewatchProcess, api_client, wait_for_job
from tests.integration.test_comparison_jobs import submit_comparison
from worker.simulator.dsm_pair import make_dsm_pair, write_dsm_pair

pytestmark = pytest.mark.integration


def test_a_failed_report_stage_is_retried_with_backoff(
    tmp_path: Path, start_worker: Callable[..., SlidewatchProcess]
) -> None:
    settings = Settings(data_dir=tmp_path / "data")
    client, auth = api_client(settings)
    start_worker(settings)
    pair = make_dsm_pair(shape=(240, 240), pixel_size_m=1.0, shift_m=(1.3, -0.7, 0.2), seed=7)
    site, comparison_job = submit_comparison(client, auth, write_dsm_pair(pair, tmp_path))
    finished = wait_for_job(
        client, auth, site, comparison_job, lambda j: j["state"] in ("succeeded", "failed")
    )
    assert finished["state"] == "succeeded", finished

    # Something else holds the path of the report's folder (a file): building fails with
    # an OSError until it goes away.
    blocker = settings.storage_dir / "reports" / str(site) / "1"
    blocker.parent.mkdir(parents=True)
    blocker.write_text("in the way")
    created = client.post(f"/api/v1/sites/{site}/reports", json={}, headers=auth)
    assert created.status_code == 202, created.text
    report = created.json()
    assert report["id"] == 1

    def retrying(job: dict) -> bool:
        return "retrying in" in (job["stages"][0]["error"] or "") or job["state"] == "failed"

    job = wait_for_job(client, auth, site, report["job_id"], retrying)
    assert job["kind"] == "report" and job["state"] == "running", job
    [build] = job["stages"]
    # Seen at its first retry, or at a later one on a loaded machine (the first lasts 2 s):
    # each waits twice as long as the one before.
    failed = re.search(r"attempt (\d+) failed, retrying in (\d+) s", build["error"])
    assert build["state"] == "pending" and failed, build
    attempt, delay = int(failed[1]), int(failed[2])
    assert delay == 2**attempt
    blocker.unlink()

    job = wait_for_job(
        client, auth, site, report["job_id"], lambda j: j["state"] in ("succeeded", "failed")
    )
    assert job["state"] == "succeeded", job
    assert job["stages"][0]["attempts"] >= attempt + 1 and job["stages"][0]["error"] is None
    built = client.get(f"/api/v1/sites/{site}/reports/{report['id']}", headers=auth).json()
    assert built["status"] == "succeeded" and built["summary"]["detections"] == 1
    assert client.get(built["pdf_url"], headers=auth).status_code == 200
