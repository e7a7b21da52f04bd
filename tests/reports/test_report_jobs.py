"""A report is built by a job like any other: listed with the site's jobs, its progress
streamed, its failure recorded on the job and the report, and retried from the jobs API.
The stage runs in this process exactly as a worker runs it."""

import threading
from datetime import UTC, datetime, timedelta

import pytest
from fastapi import FastAPI
from fastapi.testclient import TestClient
from sqlalchemy import func, select, update

from backend.config import Settings
from backend.db.migrate import upgrade
from backend.db.models import Comparison, Job, JobState, Report, Schedule, Site
from backend.db.session import make_engine
from backend.services.reports import queue_waiting_reports
from backend.services.schedules import claim_due_runs
from tests.api.test_job_events import parse_events
from tests.api_helpers import run_job_inline
from tests.monitoring_helpers import finished_comparison
from worker.celery_app import create_celery
from worker.simulator.dsm_pair import DsmPairPaths


def _request(client: TestClient, auth: dict, site: int) -> dict:
    created = client.post(f"/api/v1/sites/{site}/reports", json={}, headers=auth)
    assert created.status_code == 202, created.text
    return created.json()


def test_a_report_job_is_listed_streamed_and_built(
    report_app: FastAPI, client: TestClient, auth: dict, report_pair: DsmPairPaths
) -> None:
    ids = finished_comparison(client, auth, report_pair)
    site = ids["site"]
    report = _request(client, auth, site)
    jobs = client.get(f"/api/v1/sites/{site}/jobs", headers=auth).json()
    [job] = [j for j in jobs if j["id"] == report["job_id"]]
    assert job["kind"] == "report" and job["state"] == "queued"
    assert [s["stage"] for s in job["stages"]] == ["build"]
    with report_app.state.sessionmaker() as session:  # queued on the broker at once
        assert session.get(Job, job["id"]).stages[0].queued_at is not None
    assert {j["kind"] for j in jobs} == {"comparison", "report"}

    worker = threading.Thread(target=run_job_inline, args=(job["id"], "build"))
    worker.start()  # the stage runs while the page listens to the job's events
    response = client.get(f"/api/v1/sites/{site}/jobs/{job['id']}/events", headers=auth)
    worker.join()
    events = [data for _, data in parse_events(response.text)]
    assert events[-1]["state"] == "succeeded" and events[-1]["progress"] == 1.0

    job = client.get(f"/api/v1/sites/{site}/jobs/{job['id']}", headers=auth).json()
    [build] = job["stages"]
    assert build["attempts"] == 1 and build["result"]["comparison_id"] == ids["comparison"]
    built = client.get(f"/api/v1/sites/{site}/reports/{report['id']}", headers=auth).json()
    assert built["status"] == "succeeded" and built["job_id"] == job["id"]
    assert built["comparison_id"] == ids["comparison"] and built["summary"]["detections"] == 1
    assert client.get(built["pdf_url"], headers=auth).status_code == 200


def test_a_failed_report_is_recorded_on_its_job_and_retried_from_the_jobs_api(
    report_app: FastAPI, client: TestClient, auth: dict, report_pair: DsmPairPaths
) -> None:
    ids = finished_comparison(client, auth, report_pair)
    site = ids["site"]
    report = _request(client, auth, site)

    def set_comparison(state: JobState) -> None:
        with report_app.state.sessionmaker() as session:
            session.execute(
                update(Comparison).where(Comparison.id == ids["comparison"]).values(status=state)
            )
            session.commit()

    # By the time the report is built, its comparison is no longer a finished one: the
    # report cannot be made, and retrying at once would not help.
    set_comparison(JobState.failed)
    run_job_inline(report["job_id"], "build")
    job = client.get(f"/api/v1/sites/{site}/jobs/{report['job_id']}", headers=auth).json()
    assert job["state"] == "failed" and "no finished comparison" in job["error"]
    [build] = job["stages"]
    assert build["state"] == "failed" and build["attempts"] == 1
    failed = client.get(f"/api/v1/sites/{site}/reports/{report['id']}", headers=auth).json()
    assert failed["status"] == "failed" and "no finished comparison" in failed["error"]
    assert failed["pdf_url"] is None

    set_comparison(JobState.succeeded)
    retried = client.post(f"/api/v1/sites/{site}/jobs/{report['job_id']}/retry", headers=auth)
    assert retried.status_code == 202, retried.text
    queued = client.get(f"/api/v1/sites/{site}/reports/{report['id']}", headers=auth).json()
    assert queued["status"] == "queued" and queued["error"] is None
    run_job_inline(report["job_id"], "build")
    built = client.get(f"/api/v1/sites/{site}/reports/{report['id']}", headers=auth).json()
    assert built["status"] == "succeeded", built["error"]
    job = client.get(f"/api/v1/sites/{site}/jobs/{report['job_id']}", headers=auth).json()
    assert job["stages"][0]["attempts"] == 2


@pytest.mark.parametrize("database", ["sqlite", "postgresql"])
def test_each_waiting_report_gets_exactly_one_job(
    database: str, tmp_path, request: pytest.FixtureRequest
) -> None:
    """What the monitoring tick does after claiming due schedules: a job for each report
    without one (also one left by a tick that died), however many ticks run at once."""
    url = request.getfixturevalue("sqlite_url" if database == "sqlite" else "postgres_url")
    upgrade(url)
    engine = make_engine(url)
    celery = create_celery(Settings(data_dir=tmp_path / "data", database_url=url))
    (tmp_path / "data").mkdir()
    try:
        from sqlalchemy.orm import sessionmaker

        factory = sessionmaker(bind=engine, expire_on_commit=False)
        due = datetime(2026, 6, 1, 6, 0, tzinfo=UTC)
        with factory() as session:
            site = Site(name="ticked")
            session.add(site)
            session.flush()
            session.add(
                Schedule(site_id=site.id, cron="0 6 * * 1", timezone="UTC", next_run_at=due)
            )
            session.commit()
            [run] = claim_due_runs(session, due + timedelta(minutes=1))
        queued: list[int] = []
        barrier = threading.Barrier(3)

        def tick() -> None:
            barrier.wait()
            with factory() as session:
                queued.extend(queue_waiting_reports(celery, session))

        threads = [threading.Thread(target=tick) for _ in range(3)]
        for thread in threads:
            thread.start()
        for thread in threads:
            thread.join(timeout=30)
        assert queued == [run.report_id]
        with factory() as session:
            [job] = session.scalars(select(Job).where(Job.report_id == run.report_id)).all()
            assert job.kind == "report" and job.site_id == site.id
            assert job.stages[0].queued_at is not None
            assert session.scalar(select(func.count()).select_from(Report)) == 1
            assert queue_waiting_reports(celery, session) == []
    finally:
        engine.dispose()
