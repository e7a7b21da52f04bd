"""A job's progress reaches the page as Server-Sent Events, until it succeeds or fails."""

import json
import threading

from fastapi import FastAPI
from fastapi.testclient import TestClient
from sqlalchemy import update

from backend.db.models import Job, JobState
from tests.api_helpers import run_job_inline, upload_dsm
from worker.simulator.dsm_pair import DsmPairPaths


def parse_events(text: str) -> list[tuple[str, dict]]:
    events = []
    for block in text.split("\n\n"):
        fields = dict(
            line.split(": ", 1) for line in block.splitlines() if ": " in line and line[0] != ":"
        )
        if fields.get("event"):
            events.append((fields["event"], json.loads(fields["data"])))
    return events


def queued_comparison(client: TestClient, auth: dict, pair: DsmPairPaths) -> tuple[int, int]:
    site = client.post("/api/v1/sites", json={"name": "slope"}, headers=auth).json()["id"]
    pre = upload_dsm(client, auth, site, pair.pre, "2026-06-01T10:00:00Z")
    post = upload_dsm(client, auth, site, pair.post, "2026-07-01T10:00:00Z")
    created = client.post(
        f"/api/v1/sites/{site}/comparisons",
        json={"pre_survey_id": pre["id"], "post_survey_id": post["id"], "method": "threshold"},
        headers=auth,
    ).json()
    return site, created["job"]["id"]


def test_stages_and_progress_are_pushed_until_the_job_succeeds(
    client: TestClient, auth: dict, dsm_pair_files: DsmPairPaths
) -> None:
    site, job = queued_comparison(client, auth, dsm_pair_files)
    worker = threading.Thread(target=run_job_inline, args=(job,))
    worker.start()  # the stages run while the page listens
    response = client.get(f"/api/v1/sites/{site}/jobs/{job}/events", headers=auth)
    worker.join()
    assert response.status_code == 200
    assert response.headers["content-type"].startswith("text/event-stream")
    assert response.text.startswith("retry: ")
    events = parse_events(response.text)
    assert all(name == "job" for name, _ in events)
    jobs = [data for _, data in events]
    assert jobs[-1]["state"] == "succeeded" and jobs[-1]["progress"] == 1.0
    assert len(jobs) >= 3, "progress while running, not only the end"
    progress = [j["progress"] for j in jobs]
    assert progress == sorted(progress)
    seen_running = {s["stage"] for j in jobs for s in j["stages"] if s["state"] == "running"}
    assert seen_running, "no stage was seen running"


def test_a_failed_job_ends_the_stream_with_its_reason(
    client: TestClient, auth: dict, app: FastAPI, dsm_pair_files: DsmPairPaths
) -> None:
    site, job = queued_comparison(client, auth, dsm_pair_files)
    with app.state.sessionmaker() as session:
        session.execute(
            update(Job)
            .where(Job.id == job)
            .values(state=JobState.failed, error="coregister: the DSMs share no stable terrain")
        )
        session.commit()
    response = client.get(f"/api/v1/sites/{site}/jobs/{job}/events", headers=auth)
    [(_event, data)] = parse_events(response.text)
    assert data["state"] == "failed" and "no stable terrain" in data["error"]


def test_events_of_another_sites_job_are_refused(
    client: TestClient, auth: dict, dsm_pair_files: DsmPairPaths
) -> None:
    _site, job = queued_comparison(client, auth, dsm_pair_files)
    other = client.post("/api/v1/sites", json={"name": "other"}, headers=auth).json()["id"]
    response = client.get(f"/api/v1/sites/{other}/jobs/{job}/events", headers=auth)
    assert response.status_code == 404
